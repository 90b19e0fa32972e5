"""Small helpers over time series shared by the experiments' reports."""

from __future__ import annotations

import numpy as np


def value_at(times: np.ndarray, values: np.ndarray, t: float) -> float:
    """The value at the first sample not before ``t`` (the last one when ``t`` is past the end)."""
    return float(values[min(np.searchsorted(times, t), len(values) - 1)])
