"""A trajectory: N poses of a sensor in a world frame, with their times (a record, not a file;
its file formats are in ``evp.io.trajectory``)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from evp.geometry.transforms import poses_from_xyz_quat, quat_xyzw_from_matrices


@dataclass(frozen=True)
class Trajectory:
    """N poses of a sensor in a world frame; ``timestamps`` is None for KITTI files without times."""

    positions: np.ndarray  # (N, 3) metres
    quats_xyzw: np.ndarray  # (N, 4) Hamilton, scalar last, unit norm
    timestamps: np.ndarray | None = None  # (N,) seconds
    name: str = ""

    def __post_init__(self) -> None:
        n = len(self.positions)
        if self.positions.shape != (n, 3) or self.quats_xyzw.shape != (n, 4):
            raise ValueError("positions must be (N, 3) and quaternions (N, 4)")
        if self.timestamps is not None and self.timestamps.shape != (n,):
            raise ValueError("timestamps must be (N,)")

    @staticmethod
    def from_poses(poses: np.ndarray, timestamps: np.ndarray | None = None, name: str = "") -> Trajectory:
        """From a stack of 4x4 poses."""
        poses = np.asarray(poses, dtype=float).reshape(-1, 4, 4)
        stamps = None if timestamps is None else np.asarray(timestamps, dtype=float)
        return Trajectory(poses[:, :3, 3].copy(), quat_xyzw_from_matrices(poses[:, :3, :3]), stamps, name)

    def __len__(self) -> int:
        return len(self.positions)

    @property
    def poses(self) -> np.ndarray:
        """(N, 4, 4) camera-to-world transforms."""
        return poses_from_xyz_quat(self.positions, self.quats_xyzw)

    @property
    def path_length(self) -> float:
        """Sum of the distances between consecutive positions (metres)."""
        if len(self) < 2:
            return 0.0
        return float(np.sum(np.linalg.norm(np.diff(self.positions, axis=0), axis=1)))

    @property
    def duration(self) -> float:
        if self.timestamps is None or len(self) < 2:
            return 0.0
        return float(self.timestamps[-1] - self.timestamps[0])

    def select(self, indices: np.ndarray) -> Trajectory:
        """The poses at the given indices (or boolean mask)."""
        stamps = None if self.timestamps is None else self.timestamps[indices]
        return Trajectory(self.positions[indices], self.quats_xyzw[indices], stamps, self.name)

    def with_timestamps(self, timestamps: np.ndarray) -> Trajectory:
        stamps = np.asarray(timestamps, dtype=float)
        if len(stamps) != len(self):
            raise ValueError(f"{len(stamps)} timestamps for {len(self)} poses")
        return Trajectory(self.positions, self.quats_xyzw, stamps, self.name)
