"""What a Kalman update did with one measurement, and the chi-square gate that decides it.

Shared by the 3-D navigation filter and the planar odometry filter: both test the normalised
innovation squared ``nis = r' S^-1 r`` of a residual ``r`` with covariance ``S``, which is
chi-square distributed with ``len(r)`` degrees of freedom when the filter is consistent, against
the quantile that lets ``probability`` of consistent measurements through.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass, field
from functools import lru_cache

import numpy as np
from scipy.stats import chi2


class UpdateStatus(enum.Enum):
    ACCEPTED = "accepted"
    GATED = "gated"  # innovation beyond the chi-square gate
    REFUSED = "refused"  # the reading itself is unusable (NaN, out of range, tilted)
    TOO_OLD = "too_old"  # older than the delayed horizon, or than the first IMU sample
    NO_IMU = "no_imu"  # no IMU sample yet: nothing to fuse it into


@dataclass(frozen=True)
class Innovation:
    """What one update did: residual and its covariance ``S``, the normalised innovation squared
    against the gate's ``threshold``, and why it was not fused if it was not. ``kind`` names the
    sensor (``"gps"``, ``"visual"``, ``"range:<beacon id>"``...)."""

    timestamp: float
    kind: str
    status: UpdateStatus
    residual: np.ndarray = field(default_factory=lambda: np.zeros(0))
    covariance: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))
    nis: float = float("nan")
    threshold: float = float("nan")
    message: str = ""

    @property
    def accepted(self) -> bool:
        return self.status is UpdateStatus.ACCEPTED


@lru_cache(maxsize=64)
def chi_square_gate(probability: float, dof: int) -> float:
    """The NIS below which ``probability`` of a consistent ``dof``-dimensional innovation falls."""
    if not 0 < probability < 1:
        raise ValueError(f"gate probability must be in (0, 1), not {probability}")
    if dof < 1:
        raise ValueError(f"an innovation has at least one dimension, not {dof}")
    return float(chi2.ppf(probability, dof))


def gated_innovation(timestamp: float, kind: str, residual: np.ndarray, S: np.ndarray, probability: float, gate: bool = True) -> tuple[Innovation, np.ndarray]:
    """The innovation of ``residual`` with covariance ``S`` after the gate (``gate=False`` lets it
    through whatever its size, for re-applying an already accepted update), and ``S^-1``."""
    S_inv = np.linalg.inv(S)
    nis = float(residual @ S_inv @ residual)
    threshold = chi_square_gate(probability, len(residual))
    status = UpdateStatus.ACCEPTED if (nis <= threshold or not gate) else UpdateStatus.GATED
    message = "" if status is UpdateStatus.ACCEPTED else f"normalised innovation squared {nis:.1f} > gate {threshold:.1f}"
    return Innovation(timestamp, kind, status, residual, S, nis, threshold, message), S_inv
