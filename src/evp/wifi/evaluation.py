"""Scoring fingerprinting methods on test sets: mean 2-D error and floor accuracy per set, over
all sets, and over the test samples that stand where the survey never stood."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from evp.wifi.fingerprints import Fingerprints, aligned, seen_in
from evp.wifi.knn import KnnMethod, build_radio_map, locate


@dataclass(frozen=True)
class Scores:
    """One method on a set of test samples; ``not_located``: scans that heard no known access point
    (left out of the error and the floor accuracy, counted here)."""

    mean_error_m: float
    floor_accuracy: float
    samples: int
    not_located: int

    def as_dict(self) -> dict:
        return {
            "mean_error_m": _number(self.mean_error_m),
            "floor_accuracy": _number(self.floor_accuracy),
            "samples": self.samples,
            "not_located": self.not_located,
        }


def _number(value: float) -> float | None:
    """JSON has no NaN: a figure over no sample is null."""
    return None if np.isnan(value) else value


def _scores(errors: np.ndarray, floor_right: np.ndarray, located: np.ndarray) -> Scores:
    mean = float(errors[located].mean()) if located.any() else float("nan")
    accuracy = float(floor_right[located].mean()) if located.any() else float("nan")
    return Scores(mean, accuracy, len(errors), int((~located).sum()))


def evaluate_methods(
    survey: Fingerprints, test_sets: dict[str, Fingerprints], methods: list[KnnMethod], not_detected_dbm: float, place_tolerance_m: float
) -> dict:
    """``{"methods": {name: {"mean_error_m", "floor_accuracy", "unseen_points_mean_error_m",
    "per_set": {set: {...}}}}}``: the overall figures pool every test sample of every set."""
    unseen = {name: ~seen_in(test, survey, place_tolerance_m) for name, test in test_sets.items()}
    results = {}
    for method in methods:
        radio_map = build_radio_map(survey, method, not_detected_dbm, place_tolerance_m)
        per_set, errors, right, located, new = {}, [], [], [], []
        for name, test in test_sets.items():
            found = locate(radio_map, aligned(test, survey.access_points), method)
            error = np.linalg.norm(found.positions - test.positions, axis=1)
            floor_right = found.floors == test.floors
            scores = _scores(error, floor_right, found.located)
            unseen_scores = _scores(error[unseen[name]], floor_right[unseen[name]], found.located[unseen[name]])
            per_set[name] = {**scores.as_dict(), "unseen_samples": int(unseen[name].sum()), "unseen_mean_error_m": _number(unseen_scores.mean_error_m)}
            errors.append(error), right.append(floor_right), located.append(found.located), new.append(unseen[name])
        error, floor_right, found_any, new_any = (np.concatenate(a) for a in (errors, right, located, new))
        overall = _scores(error, floor_right, found_any)
        results[method.name] = {
            "mean_error_m": _number(overall.mean_error_m),
            "floor_accuracy": _number(overall.floor_accuracy),
            "unseen_points_mean_error_m": _number(_scores(error[new_any], floor_right[new_any], found_any[new_any]).mean_error_m),
            "per_set": per_set,
        }
    return {"methods": results}
