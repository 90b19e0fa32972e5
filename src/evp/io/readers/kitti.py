"""KITTI odometry sequences: ``image_0/`` (or ``image_2/``), ``times.txt``, ``calib.txt`` and poses.

Variants read: the grey left camera ``image_0/`` (preferred) or, in the colour-only download, the
colour left camera ``image_2/`` with its ``P2`` projection; a sequence without ``times.txt`` gets
nominal stamps at KITTI's camera rate with a warning; ground truth from ``poses.txt`` /
``poses_kitti.txt`` in the sequence folder or the benchmark layout's ``dataset/poses/NN.txt``
beside ``dataset/sequences/NN``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from evp.calib.camera_files import is_kitti_calib, kitti_camera, read_kitti_projection
from evp.errors import DatasetError
from evp.io.dataset import Dataset, check_increasing, image_file_frames, image_size
from evp.io.trajectory import TrajectoryFormat, read_timestamps, read_trajectory
from evp.types import Trajectory

# KITTI's cameras are triggered by the Velodyne at 10 Hz (Geiger et al., "Vision meets Robotics:
# The KITTI Dataset", IJRR 2013, section 2); times.txt measures about 0.1036 s between frames.
KITTI_FRAME_RATE_HZ = 10.0
IMAGE_FOLDERS = {"image_0": 0, "image_2": 2}  # the left camera, grey then colour, and its P line


def _camera0_to_camera(P: np.ndarray) -> np.ndarray:
    """T_cam0_camN of a rectified camera whose projection is ``P = K [I | t]`` (x_camN = x_cam0 + t)."""
    pose = np.eye(4)
    pose[:3, 3] = -np.linalg.solve(P[:, :3], P[:, 3])
    return pose


def _image_folder(path: Path) -> Path | None:
    return next((path / name for name in IMAGE_FOLDERS if (path / name).is_dir()), None)


class KittiReader:
    name = "kitti"
    description = "KITTI odometry sequence (image_0/ or image_2/, times.txt, calib.txt, poses)"
    looks_for = "image_0/ or image_2/, with times.txt or a calib.txt of P0:/P2: lines"

    def detect(self, path: Path) -> bool:
        if not path.is_dir() or _image_folder(path) is None:
            return False
        return (path / "times.txt").is_file() or is_kitti_calib(path / "calib.txt")

    def read(self, path: Path) -> Dataset:
        folder = _image_folder(path)
        if folder is None:
            raise DatasetError(path, f"no image folder ({' or '.join(IMAGE_FOLDERS)})")
        images = sorted(folder.glob("*.png"))
        if not images:
            raise DatasetError(folder, "no PNG images")
        width, height = image_size(images[0])
        camera = IMAGE_FOLDERS[folder.name]
        times_file = path / "times.txt"
        if times_file.is_file():
            times = read_timestamps(times_file)
            if len(times) < len(images):
                raise DatasetError(times_file, f"{len(times)} times for {len(images)} images")
            times = times[: len(images)]
            check_increasing(times_file, times, "frame")
        else:
            times = np.arange(len(images)) / KITTI_FRAME_RATE_HZ
        projection = read_kitti_projection(path / "calib.txt", camera)
        dataset = Dataset(path.name, self.name, path, kitti_camera(projection, width, height, camera), times, image_file_frames(times, images))
        if not times_file.is_file():
            dataset.warnings.append(f"no times.txt: frames stamped at KITTI's nominal {KITTI_FRAME_RATE_HZ:g} Hz (0.1 s apart from 0)")
        if camera != 0:
            dataset.notes.append(f"images from {folder.name}/ (no image_0/), calibration from P{camera}")
        self._ground_truth(path, dataset, len(images), times, _camera0_to_camera(projection))
        return dataset

    @staticmethod
    def _ground_truth(path: Path, dataset: Dataset, count: int, times: np.ndarray, t_cam0_cam: np.ndarray) -> None:
        """KITTI poses are camera 0's; another camera's follow through its rectified offset."""
        for candidate in [
            path / "poses_kitti.txt",
            path / "poses.txt",
            path.parent / "poses" / f"{path.name}.txt",
            path.parent.parent / "poses" / f"{path.name}.txt",
        ]:
            if candidate.is_file():
                poses = read_trajectory(candidate, TrajectoryFormat.KITTI)
                if len(poses) < count:
                    raise DatasetError(candidate, f"{len(poses)} poses for {count} images")
                cam0 = poses.select(np.arange(count))
                if np.allclose(t_cam0_cam, np.eye(4)):
                    dataset.ground_truth = cam0.with_timestamps(times)
                    dataset.ground_truth_note = f"{candidate.name}: T_world_cam0 (KITTI)"
                else:
                    dataset.ground_truth = Trajectory.from_poses(cam0.poses @ t_cam0_cam, times, "groundtruth_cam")
                    dataset.ground_truth_note = f"{candidate.name}: T_world_cam0 (KITTI) x the rectified offset of {dataset.camera.name}"
                return
