"""International Standard Atmosphere (troposphere): pressure <-> altitude, for barometers."""

from __future__ import annotations

import numpy as np

SEA_LEVEL_PA = 101325.0
_LAPSE = 2.25577e-5  # 1/m
_EXPONENT = 5.25588


def pressure_from_altitude(altitude_m: np.ndarray) -> np.ndarray:
    return SEA_LEVEL_PA * (1.0 - _LAPSE * np.asarray(altitude_m, dtype=float)) ** _EXPONENT


def altitude_from_pressure(pressure_pa: np.ndarray) -> np.ndarray:
    return (1.0 - (np.asarray(pressure_pa, dtype=float) / SEA_LEVEL_PA) ** (1.0 / _EXPONENT)) / _LAPSE
