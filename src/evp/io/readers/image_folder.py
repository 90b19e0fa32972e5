"""A folder of images with a timestamps file, a calibration file and optional TUM ground truth.

Timestamps: ``images.txt`` / ``timestamps.txt`` as ``time path`` lines, or ``times.txt`` with one
time per line for the sorted images. Calibration: ``camera.yaml``/``calibration.yaml`` (any format
:func:`evp.calib.camera_files.read_camera` reads) or ``calib.txt`` (``fx fy cx cy k1 k2 p1 p2 k3``,
or KITTI's ``P0: ...`` lines, read as camera 0's projection). Ground truth: ``groundtruth.txt`` (TUM).
"""

from __future__ import annotations

from pathlib import Path

from evp.calib.camera_files import is_kitti_calib, read_camera
from evp.errors import CalibrationError, DatasetError
from evp.io.dataset import Dataset, check_increasing, image_file_frames, image_size
from evp.io.text_tables import read_named_lines
from evp.io.trajectory import read_timestamps, read_trajectory

IMAGE_SUFFIXES = {".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".pgm"}
NAMED_STAMP_FILES = ("images.txt", "timestamps.txt", "frames.txt")
CALIBRATION_FILES = ("camera.yaml", "calibration.yaml", "calib.yaml", "calib.txt")


def _image_dir(path: Path) -> Path:
    return path / "images" if (path / "images").is_dir() else path


def _calibration_file(path: Path) -> Path | None:
    return next((path / n for n in CALIBRATION_FILES if (path / n).is_file()), None)


class ImageFolderReader:
    name = "image-folder"
    description = "image folder + timestamps file (images.txt or times.txt) + calibration (camera.yaml or calib.txt)"
    looks_for = "images (here or in images/) with " + ", ".join(NAMED_STAMP_FILES) + " or times.txt"

    def detect(self, path: Path) -> bool:
        if not path.is_dir():
            return False
        has_stamps = any((path / n).is_file() for n in NAMED_STAMP_FILES) or (path / "times.txt").is_file()
        return has_stamps and any(p.suffix.lower() in IMAGE_SUFFIXES for p in _image_dir(path).iterdir())

    def read(self, path: Path) -> Dataset:
        stamp_file = next((path / n for n in NAMED_STAMP_FILES if (path / n).is_file()), None)
        if stamp_file is not None:
            stamps, names, lines = read_named_lines(stamp_file)
            paths = [path / name for name in names]
        else:
            stamp_file = path / "times.txt"
            paths = sorted(p for p in _image_dir(path).iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)
            stamps = read_timestamps(stamp_file)
            lines = None
            if len(stamps) != len(paths):
                raise DatasetError(stamp_file, f"{len(stamps)} times for {len(paths)} images")
        check_increasing(stamp_file, stamps, "image", lines)
        missing = [p for p in paths if not p.is_file()]
        if missing:
            raise DatasetError(stamp_file, f"{len(missing)} listed images are missing, first {missing[0].name}")
        dataset = Dataset(path.name, self.name, path, None, stamps, image_file_frames(stamps, paths))
        calibration = _calibration_file(path)
        if calibration is None:
            dataset.notes.append(f"no calibration file ({', '.join(CALIBRATION_FILES)}): give --camera FILE|PROFILE")
        else:
            width, height = image_size(paths[0])
            dataset.camera = read_camera(calibration, width, height)
            if (dataset.camera.width, dataset.camera.height) != (width, height):
                raise CalibrationError(calibration, f"calibration is for {dataset.camera.width}x{dataset.camera.height} but images are {width}x{height}")
            if is_kitti_calib(calibration):  # KITTI's P0: lines, not the plain numbers of RPG's calib.txt
                dataset.notes.append(f"calibration: {calibration.name} in KITTI form, camera 0's projection P0 (rectified, no distortion)")
        if (path / "groundtruth.txt").is_file():
            dataset.ground_truth = read_trajectory(path / "groundtruth.txt")
            dataset.ground_truth_note = "groundtruth.txt (TUM)"
        return dataset
