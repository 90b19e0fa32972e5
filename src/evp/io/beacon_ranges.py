"""Beacon-range rows of a dataset file checked into :class:`BeaconRange` records: a bad row is
dropped with a warning that names it, never silently, and never costs the other rows."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from evp.types import BeaconRange


def beacon_range_records(
    path: Path,
    times: np.ndarray,
    beacon_ids: list[str],
    ranges_m: np.ndarray,
    line_numbers: list[int],
    beacons: dict[str, tuple[float, float, float]],
    warnings: list[str],
) -> list[BeaconRange]:
    """Records for the rows whose beacon is in ``beacons`` and whose range is a finite positive
    number, sorted by time (stable: rows with equal times keep the file's order). Each kind of
    dropped row, and a file not in time order, adds one line to ``warnings`` (first line named)."""
    unknown = [i for i, name in enumerate(beacon_ids) if name not in beacons]
    invalid = [i for i, value in enumerate(ranges_m) if not (math.isfinite(value) and value > 0)]
    if unknown:
        names = sorted({beacon_ids[i] for i in unknown})
        warnings.append(
            f"{path}: {len(unknown)} ranges to beacons not in the beacon list ({', '.join(names)}) dropped, first at line {line_numbers[unknown[0]]}"
        )
    if invalid:
        warnings.append(f"{path}: {len(invalid)} ranges that are not finite positive numbers dropped, first at line {line_numbers[invalid[0]]}")
    dropped = set(unknown) | set(invalid)
    keep = np.array([i for i in range(len(times)) if i not in dropped], dtype=int)
    backwards = np.flatnonzero(np.diff(times[keep]) < 0)
    if len(backwards):
        first = keep[backwards[0] + 1]
        warnings.append(f"{path}: ranges not in time order ({len(backwards)} steps back, first at line {line_numbers[first]}); sorted by time")
        keep = keep[np.argsort(times[keep], kind="stable")]
    return [BeaconRange(float(times[i]), beacon_ids[i], float(ranges_m[i])) for i in keep]
