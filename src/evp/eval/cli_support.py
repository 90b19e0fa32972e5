"""Reading the two files of ``evp eval`` and giving KITTI files (which have no times) their stamps."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from evp.errors import EvaluationError, EvpError
from evp.eval.evaluate import EvaluationOptions, EvaluationResult, evaluate
from evp.eval.metrics import Alignment, DeltaUnit
from evp.io.trajectory import read_timestamps, read_trajectory
from evp.types import Trajectory


def _stamped(trajectory: Trajectory, times: Path | None, other: Trajectory, label: str) -> Trajectory:
    """KITTI poses get their ``times.txt`` stamps, or, facing another KITTI file, their frame index."""
    if trajectory.timestamps is not None:
        return trajectory
    if times is not None:
        stamps = read_timestamps(times)
        if len(stamps) < len(trajectory):
            raise EvaluationError(f"{times} has {len(stamps)} times for {len(trajectory)} {label} poses")
        return trajectory.with_timestamps(stamps[: len(trajectory)])
    if other.timestamps is None or bool(np.all(np.mod(other.timestamps, 1.0) == 0)):
        return trajectory.with_timestamps(np.arange(len(trajectory), dtype=float))
    raise EvaluationError(f"the {label} is a KITTI file without times and the other trajectory has timestamps: give --{label[:3]}-times times.txt")


def run_evaluation(
    ref_path: Path,
    est_path: Path,
    align: str,
    n_align: int | None,
    max_diff: float,
    offset: float,
    ref_times: Path | None,
    est_times: Path | None,
    rpe_delta: float,
    rpe_unit: str,
    z_target: float | None,
    z_tol: float,
) -> EvaluationResult:
    try:
        options = EvaluationOptions(Alignment(align), n_align, max_diff, offset, rpe_delta, DeltaUnit(rpe_unit), False, z_target, z_tol)
    except ValueError as exc:
        raise EvpError(f"bad option: {exc} (align: none/se3/sim3, rpe unit: frames/m)") from None
    ref = read_trajectory(ref_path)
    est = read_trajectory(est_path)
    ref_stamped = _stamped(ref, ref_times, est, "reference")
    est_stamped = _stamped(est, est_times, ref_stamped, "estimate")
    return evaluate(ref_stamped, est_stamped, options)
