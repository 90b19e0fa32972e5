"""Error statistics reported by EVP (the set of seed 002's tables plus evo's)."""

from __future__ import annotations

import numpy as np

from evp.errors import EvaluationError

STATISTIC_NAMES = ("rmse", "mean", "median", "std", "min", "max", "q1", "q3", "iqr", "sse", "count")


def error_statistics(errors: np.ndarray) -> dict[str, float]:
    """rmse, mean, median, std (population, as evo), min, max, quartiles, IQR, SSE and count."""
    errors = np.asarray(errors, dtype=float)
    if errors.size == 0:
        raise EvaluationError("no errors to summarise (empty selection)")
    q1, median, q3 = np.percentile(errors, [25, 50, 75])
    return {
        "rmse": float(np.sqrt(np.mean(errors**2))),
        "mean": float(np.mean(errors)),
        "median": float(median),
        "std": float(np.std(errors)),
        "min": float(np.min(errors)),
        "max": float(np.max(errors)),
        "q1": float(q1),
        "q3": float(q3),
        "iqr": float(q3 - q1),
        "sse": float(np.sum(errors**2)),
        "count": int(errors.size),
    }
