"""Choosing a method's k inside the radio map, never on test data: leave-one-place-out
cross-validation. Each surveyed place is held out in turn (all its samples), and its samples are
located from the others; a held-out place is, like a test point that is not in the radio map, a
place the map never saw, which is the case fingerprinting must serve."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import replace

import numpy as np

from evp.wifi.fingerprints import Fingerprints, reference_points
from evp.wifi.knn import KnnMethod, build_radio_map, locate


def leave_one_place_out_error(survey: Fingerprints, method: KnnMethod, not_detected_dbm: float, place_tolerance_m: float) -> float:
    """Mean 2-D error (m) of ``method`` over every survey sample, located without its place."""
    index, count = reference_points(survey, place_tolerance_m)
    errors = []
    for place in range(count):
        held = index == place
        radio_map = build_radio_map(survey.subset(~held), method, not_detected_dbm, place_tolerance_m)
        found = locate(radio_map, survey.rss[held], method)
        errors.append(np.linalg.norm(found.positions - survey.positions[held], axis=1))
    return float(np.nanmean(np.concatenate(errors)))


def tuned_k(
    survey: Fingerprints,
    method: KnnMethod,
    candidates: list[int],
    not_detected_dbm: float,
    place_tolerance_m: float,
    advance: Callable[[], None] = lambda: None,
) -> tuple[KnnMethod, dict[int, float]]:
    """``method`` with the candidate k of least leave-one-place-out error (the smaller k on a tie),
    and the error of each candidate; ``advance`` is called after each candidate."""
    errors = {}
    for k in candidates:
        errors[k] = leave_one_place_out_error(survey, replace(method, k=k), not_detected_dbm, place_tolerance_m)
        advance()
    best = min(errors, key=lambda k: (round(errors[k], 6), k))
    return replace(method, k=best), errors
