"""EuRoC / ASL folders: ``mav0/cam0`` images, ``imu0``, ground truth, ``sensor.yaml`` calibration."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from evp.calib.camera_files import load_yaml_mapping, read_camera
from evp.errors import DatasetError
from evp.io.dataset import Dataset, check_increasing, image_file_frames
from evp.io.text_tables import read_named_lines, read_table
from evp.io.trajectory import Trajectory, read_trajectory
from evp.types import ImuSample


def _mav0(path: Path) -> Path:
    return path if path.name == "mav0" else path / "mav0"


def _t_body_sensor(path: Path) -> np.ndarray:
    data = load_yaml_mapping(path, DatasetError)
    try:
        return np.asarray(data["T_BS"]["data"], dtype=float).reshape(4, 4)
    except (KeyError, TypeError, ValueError) as exc:
        raise DatasetError(path, f"cannot read T_BS extrinsics: {exc}") from exc


class EurocReader:
    name = "euroc"
    description = "EuRoC MAV / ASL folder (mav0/cam0/data.csv, sensor.yaml, imu0, state_groundtruth_estimate0)"

    def detect(self, path: Path) -> bool:
        return path.is_dir() and (_mav0(path) / "cam0" / "data.csv").is_file()

    def read(self, path: Path) -> Dataset:
        mav0 = _mav0(path)
        root = mav0.parent
        cam_dir = mav0 / "cam0"
        stamps_ns, names, lines = read_named_lines(cam_dir / "data.csv")
        times = stamps_ns / 1e9
        check_increasing(cam_dir / "data.csv", times, "image", lines)
        paths = [cam_dir / "data" / name for name in names]
        missing = [p for p in paths if not p.is_file()]
        if missing:
            raise DatasetError(cam_dir / "data.csv", f"{len(missing)} listed images are missing, first {missing[0].name}", line=lines[paths.index(missing[0])])
        dataset = Dataset(root.name, self.name, root, read_camera(cam_dir / "sensor.yaml"), times, image_file_frames(times, paths))
        imu_csv = mav0 / "imu0" / "data.csv"
        if imu_csv.is_file():
            rows, _, _ = read_table(imu_csv, columns=7)
            dataset.imu = [ImuSample(t / 1e9, tuple(r[1:4]), tuple(r[4:7])) for t, r in zip(rows[:, 0], rows)]
        self._ground_truth(mav0, root, dataset)
        leica = mav0 / "leica0" / "data.csv"
        if leica.is_file():
            rows, _, _ = read_table(leica, columns=4)
            quats = np.tile([0.0, 0.0, 0.0, 1.0], (len(rows), 1))
            dataset.trajectories["leica0_prism_positions"] = Trajectory(rows[:, 1:4], quats, rows[:, 0] / 1e9, "leica0")
        return dataset

    def _ground_truth(self, mav0: Path, root: Path, dataset: Dataset) -> None:
        """Camera GT: body GT times cam0 extrinsics when the standard CSV exists, else a cam0 TUM file."""
        body_csv = mav0 / "state_groundtruth_estimate0" / "data.csv"
        if body_csv.is_file():
            body = read_trajectory(body_csv)
            t_body_cam = _t_body_sensor(mav0 / "cam0" / "sensor.yaml")
            dataset.ground_truth = Trajectory.from_poses(body.poses @ t_body_cam, body.timestamps, "groundtruth_cam0")
            dataset.ground_truth_note = "state_groundtruth_estimate0 (body) x cam0 T_BS: T_world_cam0"
            return
        candidates = sorted(p for p in root.glob("groundtruth*cam0*.txt") if "full" not in p.name)
        if candidates:
            dataset.ground_truth = read_trajectory(candidates[0])
            dataset.ground_truth_note = f"{candidates[0].name}: T_world_cam0"
