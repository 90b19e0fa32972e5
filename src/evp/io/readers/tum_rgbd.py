"""TUM RGB-D sequences: ``rgb.txt``, ``groundtruth.txt``, ``accelerometer.txt``.

The TUM benchmark does not ship calibration files; its published intrinsics for the three
Kinects are used by sequence name (freiburg1/2/3), a ``camera.yaml`` in the folder wins.
"""

from __future__ import annotations

from pathlib import Path

from evp.calib.camera_files import read_camera
from evp.errors import DatasetError
from evp.io.dataset import Dataset, check_increasing, image_file_frames, image_size
from evp.io.text_tables import read_named_lines, read_table
from evp.io.trajectory import read_trajectory
from evp.types import CameraModel, ImuSample

# fx fy cx cy k1 k2 p1 p2 k3, from the TUM RGB-D benchmark's camera calibration page.
TUM_INTRINSICS = {
    "freiburg1": (517.3, 516.5, 318.6, 255.3, 0.2624, -0.9531, -0.0054, 0.0026, 1.1633),
    "freiburg2": (520.9, 521.0, 325.1, 249.7, 0.2312, -0.7849, -0.0033, -0.0001, 0.9172),
    "freiburg3": (535.4, 539.2, 320.1, 247.6, 0.0, 0.0, 0.0, 0.0, 0.0),
}
ROS_DEFAULT = (525.0, 525.0, 319.5, 239.5, 0.0, 0.0, 0.0, 0.0, 0.0)


def tum_camera(path: Path, width: int, height: int) -> tuple[CameraModel, str]:
    for name in ("camera.yaml", "calibration.yaml"):
        if (path / name).is_file():
            return read_camera(path / name), name
    key = next((k for k in TUM_INTRINSICS if k in path.name or k.replace("freiburg", "fr") in path.name), None)
    values = TUM_INTRINSICS[key] if key else ROS_DEFAULT
    note = f"TUM published intrinsics ({key})" if key else "ROS default intrinsics (sequence name has no freiburg1/2/3)"
    return CameraModel(width, height, *values, name=key or "tum_default"), note


class TumRgbdReader:
    name = "tum-rgbd"
    description = "TUM RGB-D sequence folder (rgb.txt, groundtruth.txt, accelerometer.txt)"
    looks_for = "rgb.txt"

    def detect(self, path: Path) -> bool:
        return path.is_dir() and (path / "rgb.txt").is_file()

    def read(self, path: Path) -> Dataset:
        stamps, names, lines = read_named_lines(path / "rgb.txt")
        check_increasing(path / "rgb.txt", stamps, "image", lines)
        paths = [path / name for name in names]
        if not paths[0].is_file():
            raise DatasetError(path / "rgb.txt", f"image {names[0]} not found", line=lines[0])
        width, height = image_size(paths[0])
        camera, note = tum_camera(path, width, height)
        dataset = Dataset(path.name, self.name, path, camera, stamps, image_file_frames(stamps, paths))
        dataset.notes.append(f"calibration: {note}")
        if (path / "groundtruth.txt").is_file():
            dataset.ground_truth = read_trajectory(path / "groundtruth.txt")
            dataset.ground_truth_note = "groundtruth.txt: T_world_rgbcam (TUM mocap)"
        if (path / "accelerometer.txt").is_file():
            rows, _, _ = read_table(path / "accelerometer.txt", columns=4)
            nan3 = (float("nan"),) * 3
            dataset.imu = [ImuSample(r[0], nan3, tuple(r[1:4])) for r in rows]
            dataset.notes.append("accelerometer only (Kinect), no gyro")
        return dataset
