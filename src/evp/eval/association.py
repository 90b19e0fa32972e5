"""Time association of two trajectories (nearest stamp within a maximum difference, as evo does)."""

from __future__ import annotations

import numpy as np

from evp.errors import EvaluationError
from evp.types import Trajectory


def nearest_matches(stamps_short: np.ndarray, stamps_long: np.ndarray, max_diff: float) -> tuple[np.ndarray, np.ndarray]:
    """Indices (into short, into long) of each short stamp's nearest long stamp within ``max_diff``.

    ``stamps_long`` must be sorted. Ties go to the earlier stamp; one long stamp may serve several
    short ones (evo's rule, kept so that our numbers equal evo's).
    """
    if len(stamps_long) == 0 or len(stamps_short) == 0:
        return np.zeros(0, dtype=int), np.zeros(0, dtype=int)
    upper = np.minimum(np.searchsorted(stamps_long, stamps_short, side="right"), len(stamps_long) - 1)
    diff_upper = stamps_long[upper] - stamps_short
    diff_lower = np.where(upper > 0, stamps_short - stamps_long[np.maximum(upper - 1, 0)], np.inf)
    take_upper = (diff_upper <= max_diff) & (diff_upper < diff_lower)
    take_lower = ~take_upper & (diff_lower <= max_diff) & (diff_lower <= diff_upper)
    in_range = (stamps_short >= stamps_long[0] - max_diff) & (stamps_short <= stamps_long[-1] + max_diff)
    keep = in_range & (take_upper | take_lower)
    long_index = np.where(take_upper, upper, upper - 1)
    return np.flatnonzero(keep), long_index[keep]


def associate(ref: Trajectory, est: Trajectory, max_diff: float = 0.01, offset: float = 0.0) -> tuple[Trajectory, Trajectory]:
    """Pairs of poses of ``ref`` and ``est`` whose stamps (est shifted by ``offset`` s) match.

    Returns the two trajectories cut to the matched poses, in matching order.
    """
    if ref.timestamps is None or est.timestamps is None:
        raise EvaluationError("both trajectories need timestamps to be associated")
    for name, trajectory in (("reference", ref), ("estimate", est)):
        if len(trajectory) == 0:
            raise EvaluationError(f"the {name} trajectory has no poses")
    est_stamps = est.timestamps + offset
    if len(est) > len(ref):
        ref_idx, est_idx = nearest_matches(ref.timestamps, est_stamps, max_diff)
    else:
        est_idx, ref_idx = nearest_matches(est_stamps, ref.timestamps, max_diff)
    if len(ref_idx) == 0:
        raise EvaluationError(
            f"no poses matched within {max_diff} s: reference spans {ref.timestamps[0]:.3f}..{ref.timestamps[-1]:.3f} s, "
            f"estimate {est_stamps[0]:.3f}..{est_stamps[-1]:.3f} s (use --t-offset or --t-max-diff)"
        )
    return ref.select(ref_idx), est.select(est_idx)
