"""WiFi as a position sensor for a navigation filter: a scan located in the radio map, with the
1-sigma error the locator is known to have.

The error is measured, not assumed: the method's leave-one-place-out error inside the radio map
(:func:`~evp.wifi.tuning.leave_one_place_out_error`, every surveyed place located from the others,
as a place the survey never stood on is). A filter treats a fix as a 2-D Gaussian with the same
sigma on each axis; the mean distance of such an error from the truth is ``sigma sqrt(pi / 2)``
(the mean of a Rayleigh distribution), so the sigma is the measured mean error over that factor.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from evp.wifi.fingerprints import Fingerprints
from evp.wifi.knn import KnnMethod, RadioMap, build_radio_map, locate
from evp.wifi.tuning import leave_one_place_out_error

RAYLEIGH_MEAN = math.sqrt(math.pi / 2)  # mean distance of a 2-D Gaussian error, in per-axis sigmas


def scan_rss(rssi_dbm: dict[str, float], access_points: tuple[str, ...]) -> np.ndarray:
    """(A,) dBm in the radio map's access point columns, NaN for one the scan did not hear (or
    heard as a non-finite value); access points the map does not know are left out."""
    return np.array([rssi_dbm.get(name, math.nan) for name in access_points], dtype=float)


@dataclass(frozen=True)
class WifiFix:
    """A located scan: ``position`` (2,) m in the radio map's frame, ``sigma_m`` per axis."""

    timestamp: float
    position: np.ndarray
    sigma_m: float


@dataclass(frozen=True)
class WifiLocator:
    """A radio map, the method that matches scans in it, and that method's measured sigma."""

    radio_map: RadioMap
    method: KnnMethod
    sigma_m: float

    def fix(self, timestamp: float, rssi_dbm: dict[str, float]) -> WifiFix | None:
        """The scan's position, or None when it heard no access point of the radio map."""
        rss = scan_rss(rssi_dbm, self.radio_map.fingerprints.access_points)
        found = locate(self.radio_map, rss[None], self.method)
        if not found.located[0]:
            return None
        return WifiFix(timestamp, found.positions[0], self.sigma_m)


def wifi_locator(survey: Fingerprints, method: KnnMethod, not_detected_dbm: float, place_tolerance_m: float) -> WifiLocator:
    """The locator of ``method`` on ``survey``, its sigma from the leave-one-place-out error."""
    error = leave_one_place_out_error(survey, method, not_detected_dbm, place_tolerance_m)
    return WifiLocator(build_radio_map(survey, method, not_detected_dbm, place_tolerance_m), method, error / RAYLEIGH_MEAN)
