"""KITTI odometry sequences: ``image_0/``, ``times.txt``, ``calib.txt`` (P0) and poses."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from evp.errors import CalibrationError, DatasetError
from evp.io.dataset import Dataset, check_increasing, image_file_frames, image_size
from evp.io.trajectory import TrajectoryFormat, read_timestamps, read_trajectory
from evp.types import CameraModel


def read_kitti_calib(path: Path, width: int, height: int) -> CameraModel:
    """Camera 0 from the ``P0:`` projection matrix of a KITTI ``calib.txt`` (rectified, no distortion)."""
    if not path.is_file():
        raise CalibrationError(path, "calib.txt not found")
    for number, line in enumerate(path.read_text().splitlines(), start=1):
        if line.startswith("P0:"):
            try:
                P = np.array([float(v) for v in line.split()[1:]]).reshape(3, 4)
            except ValueError as exc:
                raise CalibrationError(path, f"P0 must hold 12 numbers: {exc}", line=number) from exc
            return CameraModel(width, height, float(P[0, 0]), float(P[1, 1]), float(P[0, 2]), float(P[1, 2]), name="kitti_cam0")
    raise CalibrationError(path, "no 'P0:' line")


class KittiReader:
    name = "kitti"
    description = "KITTI odometry sequence (image_0/, times.txt, calib.txt, poses)"

    def detect(self, path: Path) -> bool:
        return path.is_dir() and (path / "image_0").is_dir() and (path / "times.txt").is_file()

    def read(self, path: Path) -> Dataset:
        images = sorted((path / "image_0").glob("*.png"))
        if not images:
            raise DatasetError(path / "image_0", "no PNG images")
        times = read_timestamps(path / "times.txt")
        if len(times) < len(images):
            raise DatasetError(path / "times.txt", f"{len(times)} times for {len(images)} images")
        times = times[: len(images)]
        check_increasing(path / "times.txt", times, "frame")
        width, height = image_size(images[0])
        dataset = Dataset(path.name, self.name, path, read_kitti_calib(path / "calib.txt", width, height), times, image_file_frames(times, images))
        for candidate in [path / "poses_kitti.txt", path / "poses.txt", path.parent / "poses" / f"{path.name}.txt"]:
            if candidate.is_file():
                poses = read_trajectory(candidate, TrajectoryFormat.KITTI)
                if len(poses) < len(images):
                    raise DatasetError(candidate, f"{len(poses)} poses for {len(images)} images")
                dataset.ground_truth = poses.select(np.arange(len(images))).with_timestamps(times)
                dataset.ground_truth_note = f"{candidate.name}: T_world_cam0 (KITTI)"
                break
        return dataset
