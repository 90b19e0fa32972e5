"""Absolute and relative pose errors, after optional alignment, following evo's definitions.

APE: E_i = P_est,i^-1 P_ref,i; translation error is |p_est - p_ref|, rotation error the angle of E_i.
RPE: E_ij = (Q_i^-1 Q_j)^-1 (P_i^-1 P_j) for reference Q and estimate P over index pairs (i, j)
chosen on the estimate, ``delta`` frames or metres of travelled path apart.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass

import numpy as np

from evp.errors import EvaluationError
from evp.geometry.alignment import Similarity, umeyama
from evp.geometry.transforms import rotation_angle, se3_inverse
from evp.types import Trajectory


class Alignment(enum.Enum):
    NONE = "none"
    SE3 = "se3"
    SIM3 = "sim3"


class DeltaUnit(enum.Enum):
    FRAMES = "frames"
    METERS = "m"


def align_trajectory(ref: Trajectory, est: Trajectory, mode: Alignment, n_align: int | None = None) -> tuple[Trajectory, Similarity]:
    """``est`` mapped onto ``ref`` (matched pose for pose) by Umeyama on the first ``n_align`` poses."""
    if mode is Alignment.NONE:
        return est, Similarity.identity()
    count = len(est) if n_align is None else min(n_align, len(est))
    if count < 3:
        raise EvaluationError(f"alignment needs at least 3 matched poses, got {count}")
    transform = umeyama(est.positions[:count], ref.positions[:count], with_scale=mode is Alignment.SIM3)
    aligned = Trajectory.from_poses(transform.apply_to_poses(est.poses), est.timestamps, est.name)
    return aligned, transform


def ape_translation(ref: Trajectory, est: Trajectory) -> np.ndarray:
    """Per-pose position error (metres)."""
    return np.linalg.norm(est.positions - ref.positions, axis=1)


def ape_translation_xy(ref: Trajectory, est: Trajectory) -> np.ndarray:
    """Per-pose horizontal (x, y) position error, as reported by seed 000."""
    return np.linalg.norm(est.positions[:, :2] - ref.positions[:, :2], axis=1)


def ape_rotation_deg(ref: Trajectory, est: Trajectory) -> np.ndarray:
    """Per-pose rotation error (degrees)."""
    relative = np.swapaxes(est.poses[:, :3, :3], 1, 2) @ ref.poses[:, :3, :3]
    return np.degrees(rotation_angle(relative))


def rpe_pairs(poses: np.ndarray, delta: float, unit: DeltaUnit, all_pairs: bool = False) -> list[tuple[int, int]]:
    """Index pairs ``delta`` apart (evo's ``filter_pairs_by_index`` / ``filter_pairs_by_path``)."""
    n = len(poses)
    if unit is DeltaUnit.FRAMES:
        step = int(delta)
        if step < 1:
            raise EvaluationError(f"RPE delta must be at least 1 frame, got {delta}")
        if all_pairs:
            return [(i, i + step) for i in range(n - step)]
        ids = list(range(0, n, step))
        return list(zip(ids, ids[1:]))
    if delta <= 0:
        raise EvaluationError(f"RPE delta must be positive, got {delta} m")
    steps = np.linalg.norm(np.diff(poses[:, :3, 3], axis=0), axis=1)
    if all_pairs:
        distances = np.concatenate([[0.0], np.cumsum(steps)])
        pairs = []
        for i in range(n - 1):
            ahead = distances[i + 1 :] - distances[i]
            j = int(np.argmin(np.abs(ahead - delta)))
            if abs(ahead[j] - delta) <= 0.1 * delta:
                pairs.append((i, i + 1 + j))
        return pairs
    ids = [0]
    travelled = 0.0
    for i, step in enumerate(steps, start=1):
        travelled += float(step)
        if travelled >= delta:
            ids.append(i)
            travelled = 0.0
    return list(zip(ids, ids[1:]))


@dataclass(frozen=True)
class RelativeErrors:
    pairs: list[tuple[int, int]]
    translation: np.ndarray  # metres
    rotation_deg: np.ndarray


def relative_pose_errors(ref: Trajectory, est: Trajectory, delta: float = 1, unit: DeltaUnit = DeltaUnit.FRAMES, all_pairs: bool = False) -> RelativeErrors:
    """RPE over pairs chosen on the estimate."""
    est_poses = est.poses
    ref_poses = ref.poses
    pairs = rpe_pairs(est_poses, delta, unit, all_pairs)
    if not pairs:
        raise EvaluationError(f"RPE with delta {delta} {unit.value} found no pose pairs; use a smaller delta")
    i, j = np.array(pairs).T
    ref_rel = se3_inverse(ref_poses[i]) @ ref_poses[j]
    est_rel = se3_inverse(est_poses[i]) @ est_poses[j]
    errors = se3_inverse(ref_rel) @ est_rel
    return RelativeErrors(pairs, np.linalg.norm(errors[:, :3, 3], axis=1), np.degrees(rotation_angle(errors[:, :3, :3])))
