"""Checking GPS fixes before they are trusted for alignment: specific errors or warnings, never silence."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from evp.errors import DataError
from evp.fusion.geodesy import EnuFrame
from evp.types import GpsFix


class AlignmentError(DataError):
    """The GPS/odometry data cannot give a trustworthy alignment (too few pairs, no lock...)."""


@dataclass
class GpsTrack:
    """Usable fixes in ENU at ``frame`` (times on the GPS clock), plus what was dropped and why."""

    frame: EnuFrame
    times: np.ndarray
    enu: np.ndarray
    horizontal_sigma_m: np.ndarray
    warnings: list[str] = field(default_factory=list)

    def __len__(self) -> int:
        return len(self.times)

    def select(self, mask: np.ndarray) -> GpsTrack:
        return GpsTrack(self.frame, self.times[mask], self.enu[mask], self.horizontal_sigma_m[mask], self.warnings)


def clean_gps(fixes: list[GpsFix], frame: EnuFrame | None = None, max_vertical_rate_m_s: float = 30.0, default_sigma_m: float = 3.0) -> GpsTrack:
    """Drop fixes without lock or with NaNs, out-of-order or duplicate stamps, and altitude jumps
    faster than any drone climbs; each kind of drop is reported once in ``warnings``."""
    warnings: list[str] = []
    finite = [f for f in fixes if all(math.isfinite(v) for v in (f.timestamp, f.latitude_deg, f.longitude_deg, f.altitude_m))]
    if len(finite) < len(fixes):
        warnings.append(f"{len(fixes) - len(finite)} GPS fixes without lock or with NaN values were dropped")
    ordered: list[GpsFix] = []
    for fix in finite:
        if ordered and fix.timestamp <= ordered[-1].timestamp:
            continue
        ordered.append(fix)
    if len(ordered) < len(finite):
        warnings.append(f"{len(finite) - len(ordered)} GPS fixes out of time order or duplicated were dropped")
    if len(ordered) < 2:
        raise AlignmentError(f"only {len(ordered)} usable GPS fixes (of {len(fixes)}): nothing to align to")
    kept = [ordered[0]]
    for fix in ordered[1:]:
        rate = abs(fix.altitude_m - kept[-1].altitude_m) / (fix.timestamp - kept[-1].timestamp)
        if rate <= max_vertical_rate_m_s:
            kept.append(fix)
    if len(kept) < len(ordered):
        warnings.append(f"{len(ordered) - len(kept)} GPS fixes with altitude jumps faster than {max_vertical_rate_m_s} m/s were dropped")
    frame = frame or EnuFrame.at(kept[0])
    sigma = np.array([f.horizontal_accuracy_m if math.isfinite(f.horizontal_accuracy_m) and f.horizontal_accuracy_m > 0 else default_sigma_m for f in kept])
    return GpsTrack(frame, np.array([f.timestamp for f in kept]), frame.fixes_to_enu(kept), sigma, warnings)
