"""Fingerprints: RSS per access point at known places, and the radio map built from them.

RSS is in dBm with NaN where the access point was not heard. A method sees a not-heard access
point as ``not_detected_dbm`` (UJIIndoorLoc's convention: just below the weakest reading a phone
reports), so that "not heard here" is evidence as much as a reading is.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from evp.errors import DataError


@dataclass(frozen=True)
class Fingerprints:
    """``rss`` (N, A) dBm (NaN: not heard), ``positions`` (N, 2) metres, ``floors`` (N,) integers;
    the columns of ``rss`` are the access points of ``access_points``."""

    rss: np.ndarray
    positions: np.ndarray
    floors: np.ndarray
    access_points: tuple[str, ...]

    def __post_init__(self) -> None:
        n, a = self.rss.shape
        if self.positions.shape != (n, 2) or self.floors.shape != (n,):
            raise DataError(f"fingerprints: {n} RSS rows need (N, 2) positions and (N,) floors, got {self.positions.shape} and {self.floors.shape}")
        if len(self.access_points) != a:
            raise DataError(f"fingerprints: {a} RSS columns but {len(self.access_points)} access point names")

    def __len__(self) -> int:
        return len(self.rss)

    def subset(self, rows: np.ndarray) -> Fingerprints:
        return Fingerprints(self.rss[rows], self.positions[rows], self.floors[rows], self.access_points)


def reference_points(fingerprints: Fingerprints, tolerance_m: float) -> tuple[np.ndarray, np.ndarray]:
    """The distinct surveyed places, ``(index per sample (N,), count)``: samples on one floor
    within ``tolerance_m`` of each other (both axes) are one place."""
    keys = np.column_stack([np.round(fingerprints.positions / tolerance_m), fingerprints.floors])
    _, index = np.unique(keys, axis=0, return_inverse=True)
    index = index.ravel()
    return index, int(index.max()) + 1 if len(index) else 0


def averaged(fingerprints: Fingerprints, tolerance_m: float, not_detected_dbm: float) -> Fingerprints:
    """One fingerprint per surveyed place: the mean RSS of its samples, a sample that did not hear
    an access point counting as ``not_detected_dbm`` (seed 001's radio map: the mean of ~100
    samples per grid node); an access point no sample heard stays not heard."""
    index, count = reference_points(fingerprints, tolerance_m)
    filled = np.nan_to_num(fingerprints.rss, nan=not_detected_dbm)
    sums = np.zeros((count, filled.shape[1]))
    heard = np.zeros((count, filled.shape[1]))
    np.add.at(sums, index, filled)
    np.add.at(heard, index, np.isfinite(fingerprints.rss))
    samples = np.bincount(index, minlength=count)[:, None]
    rss = np.where(heard > 0, sums / samples, np.nan)
    first = np.array([np.flatnonzero(index == j)[0] for j in range(count)])
    return Fingerprints(rss, fingerprints.positions[first], fingerprints.floors[first], fingerprints.access_points)


def seen_in(test: Fingerprints, survey: Fingerprints, tolerance_m: float) -> np.ndarray:
    """(N,) bool: the test sample stands on a surveyed place (same floor, within ``tolerance_m``)."""
    close = np.all(np.abs(test.positions[:, None] - survey.positions[None]) <= tolerance_m, axis=2)
    return np.any(close & (test.floors[:, None] == survey.floors[None]), axis=1)


def aligned(scans: Fingerprints, access_points: tuple[str, ...]) -> np.ndarray:
    """The scans' RSS in the columns of ``access_points`` (NaN for one the scans do not have)."""
    if scans.access_points == access_points:
        return scans.rss
    column = {name: j for j, name in enumerate(scans.access_points)}
    out = np.full((len(scans), len(access_points)), np.nan)
    for j, name in enumerate(access_points):
        if name in column:
            out[:, j] = scans.rss[:, column[name]]
    return out
