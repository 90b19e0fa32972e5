"""A SLAM map's georeference: the similarity from its units and frame to ENU at a named origin,
fitted at the end of a georeferenced run and kept with the map, so a later flight that relocalises
in the map is georeferenced at once (seed 002's geotagged keypoints, as a whole map).

The fit is the least-squares similarity (:func:`~evp.geometry.alignment.umeyama`) from the map's
keyframe centres (map units) to the navigation filter's camera positions at the same frames,
while the filter was georeferenced and GPS trusted. Not the filter's own map-to-world states: they
follow the map's drift where the vehicle is (a random walk), and hold at the end of the run only
around where it ended; a later flight relocalises anywhere in the map, for which the one
similarity that fits all keyframes best is the estimate, and its residual (how far one similarity
is from the whole map: drift the loop closures left) the uncertainty.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from evp.geometry.alignment import umeyama
from evp.types import PoseEstimate

# Keyframes a georeference needs: a similarity has 7 degrees of freedom, and a few keyframes on a
# short track give a heading that one GPS error turns by degrees.
MIN_GEOREFERENCED_KEYFRAMES = 10


@dataclass(frozen=True)
class MapGeoreference:
    """``x_enu = scale * R @ x_map + t``, ENU at ``origin`` (latitude, longitude in degrees,
    altitude in m, WGS-84). Sigmas (1-sigma): the translation per axis in metres, the rotation in
    radians (per axis, world frame), the scale relative (its logarithm's). ``keyframes`` and
    ``residual_m`` (RMS) say what the fit rested on."""

    scale: float
    R: np.ndarray
    t: np.ndarray
    origin: tuple[float, float, float]
    translation_sigma_m: float
    rotation_sigma_rad: float
    log_scale_sigma: float
    keyframes: int
    residual_m: float

    def to_json(self) -> dict:
        """Plain numbers, as the map file's metadata keeps them."""
        return {
            "scale": self.scale,
            "R": np.asarray(self.R, float).tolist(),
            "t": np.asarray(self.t, float).tolist(),
            "origin": list(self.origin),
            "translation_sigma_m": self.translation_sigma_m,
            "rotation_sigma_rad": self.rotation_sigma_rad,
            "log_scale_sigma": self.log_scale_sigma,
            "keyframes": self.keyframes,
            "residual_m": self.residual_m,
        }

    @staticmethod
    def from_json(data: dict) -> MapGeoreference:
        """The record of :meth:`to_json` (a ``KeyError``/``ValueError`` for a malformed one: the
        reader turns it into a format error)."""
        R = np.array(data["R"], float).reshape(3, 3)
        t = np.array(data["t"], float).reshape(3)
        origin = tuple(float(v) for v in data["origin"])
        numbers = [float(data[k]) for k in ("scale", "translation_sigma_m", "rotation_sigma_rad", "log_scale_sigma", "residual_m")]
        if len(origin) != 3 or not all(math.isfinite(v) for v in [*numbers, *origin, *R.ravel(), *t]) or numbers[0] <= 0:
            raise ValueError("georeference numbers must be finite, the scale positive, the origin (lat, lon, alt)")
        if not np.allclose(R.T @ R, np.eye(3), atol=1e-6) or np.linalg.det(R) < 0:
            raise ValueError("georeference R is not a rotation")
        scale, translation_sigma, rotation_sigma, log_scale_sigma, residual = numbers
        return MapGeoreference(scale, R, t, origin, translation_sigma, rotation_sigma, log_scale_sigma, int(data["keyframes"]), residual)

    def apply(self, points_map: np.ndarray) -> np.ndarray:
        """(N, 3) map points in ENU."""
        return self.scale * np.asarray(points_map, float) @ self.R.T + self.t


def fit_georeference(centres_map: np.ndarray, positions_enu: np.ndarray, origin: tuple[float, float, float], min_sigma_m: float) -> MapGeoreference | None:
    """The similarity from keyframe centres (N, 3, map units) to the fused camera positions at the
    same frames (N, 3, ENU at ``origin``); None with fewer than
    :data:`MIN_GEOREFERENCED_KEYFRAMES` pairs or pairs on one line (the rotation about it free).

    The fused positions' errors are GPS's, correlated over a minute, so the N pairs do not average
    them down by sqrt(N) (as :func:`~evp.fusion.gps_heading.align_to_gps` reasons): the translation
    sigma is the larger of the fit's RMS residual and ``min_sigma_m`` (one GPS fix's error), the
    rotation's and the scale's that over the track's RMS spread."""
    centres_map, positions_enu = np.asarray(centres_map, float), np.asarray(positions_enu, float)
    if len(centres_map) < MIN_GEOREFERENCED_KEYFRAMES:
        return None
    similarity = umeyama(centres_map, positions_enu, with_scale=True)
    if similarity.degenerate:
        return None
    residual = float(np.sqrt(np.mean(np.sum((similarity.apply(centres_map) - positions_enu) ** 2, axis=1))))
    spread = float(np.sqrt(np.mean(np.sum((positions_enu - positions_enu.mean(axis=0)) ** 2, axis=1))))
    sigma = max(residual, min_sigma_m)
    return MapGeoreference(
        scale=similarity.scale,
        R=similarity.rotation,
        t=similarity.translation,
        origin=tuple(float(v) for v in origin),
        translation_sigma_m=sigma,
        rotation_sigma_rad=sigma / max(spread, sigma),
        log_scale_sigma=sigma / max(spread, sigma),
        keyframes=len(centres_map),
        residual_m=residual,
    )


def georeference_from_run(
    keyframes: Sequence[tuple[float, np.ndarray]], estimates: Sequence[PoseEstimate], origin: tuple[float, float, float], min_sigma_m: float
) -> MapGeoreference | None:
    """:func:`fit_georeference` over the keyframes (timestamp, centre in map units) whose frame the
    navigation stage answered georeferenced with GPS trusted (``estimates``, the stage's answers,
    ENU at ``origin``): the frames where the fused position rests on GPS, not on the filter's dead
    reckoning through an outage or a spoofing."""
    fused = {e.timestamp: e.T_world_cam[:3, 3] for e in estimates if e.tracking_state.tracked and e.georeferenced and e.gps_trusted}
    pairs = [(centre, fused[t]) for t, centre in keyframes if t in fused]
    if not pairs:
        return None
    centres, positions = (np.array(side) for side in zip(*pairs, strict=True))
    return fit_georeference(centres, positions, origin, min_sigma_m)
