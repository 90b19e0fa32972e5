"""Geodetic (WGS-84) <-> local ENU at a named origin, via pymap3d."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pymap3d

from evp.types import GpsFix


@dataclass(frozen=True)
class EnuFrame:
    """East-north-up tangent frame at (latitude, longitude, altitude) of the origin, e.g. take-off."""

    latitude_deg: float
    longitude_deg: float
    altitude_m: float

    @staticmethod
    def at(fix: GpsFix) -> EnuFrame:
        return EnuFrame(fix.latitude_deg, fix.longitude_deg, fix.altitude_m)

    def to_enu(self, latitude_deg, longitude_deg, altitude_m) -> np.ndarray:
        """(N, 3) east, north, up in metres."""
        e, n, u = pymap3d.geodetic2enu(latitude_deg, longitude_deg, altitude_m, self.latitude_deg, self.longitude_deg, self.altitude_m)
        return np.column_stack([np.atleast_1d(e), np.atleast_1d(n), np.atleast_1d(u)])

    def fixes_to_enu(self, fixes: list[GpsFix]) -> np.ndarray:
        return self.to_enu(np.array([f.latitude_deg for f in fixes]), np.array([f.longitude_deg for f in fixes]), np.array([f.altitude_m for f in fixes]))

    def to_geodetic(self, enu: np.ndarray) -> np.ndarray:
        """(N, 3) latitude, longitude (degrees), altitude (m)."""
        enu = np.atleast_2d(enu)
        lat, lon, alt = pymap3d.enu2geodetic(enu[:, 0], enu[:, 1], enu[:, 2], self.latitude_deg, self.longitude_deg, self.altitude_m)
        return np.column_stack([lat, lon, alt])
