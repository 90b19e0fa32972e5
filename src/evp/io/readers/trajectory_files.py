"""A folder of trajectory files (TUM / KITTI / EuRoC CSV) or a single one: no images, only poses."""

from __future__ import annotations

from pathlib import Path

from evp.errors import TrajectoryFormatError
from evp.io.dataset import Dataset
from evp.io.trajectory import detect_trajectory_format, read_trajectory

TRAJECTORY_SUFFIXES = {".txt", ".csv", ".tum"}


def _trajectory_files(path: Path) -> list[Path]:
    """Files under ``path`` that parse as trajectories (``times.txt`` and notes are skipped)."""
    found = []
    for candidate in sorted(path.rglob("*")) if path.is_dir() else [path]:
        if candidate.suffix.lower() not in TRAJECTORY_SUFFIXES or candidate.name.startswith("times"):
            continue
        try:
            detect_trajectory_format(candidate)
        except TrajectoryFormatError:
            continue
        found.append(candidate)
    return found


class TrajectoryFilesReader:
    name = "trajectories"
    description = "trajectory file, or folder of them (TUM, KITTI, EuRoC CSV), without images"
    looks_for = "trajectory files (TUM, KITTI, EuRoC CSV)"

    def detect(self, path: Path) -> bool:
        if path.is_file():
            return bool(_trajectory_files(path))
        return path.is_dir() and bool(_trajectory_files(path))

    def read(self, path: Path) -> Dataset:
        dataset = Dataset(path.stem if path.is_file() else path.name, self.name, path)
        for file in _trajectory_files(path):
            key = str(file.relative_to(path)) if path.is_dir() else file.name
            dataset.trajectories[key] = read_trajectory(file)
        if path.is_file():
            dataset.ground_truth = dataset.trajectories.pop(path.name)
            dataset.ground_truth_note = f"the trajectory in {path.name}"
        return dataset
