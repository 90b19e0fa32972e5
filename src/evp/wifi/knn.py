"""k-nearest-neighbour fingerprinting: the survey samples whose RSS look most like a scan, and
the position they agree on.

Distances are Euclidean over every access point the radio map knows, an access point not heard
counting as ``not_detected_dbm`` on either side. (Torres-Sospedra et al. 2015's "positive"
representation, RSS minus that floor, gives the same neighbours and the same inverse-distance
weights with this distance: it is an offset and a scale.)
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from evp.wifi.fingerprints import Fingerprints, averaged

NOT_LOCATED_FLOOR = -1  # the floor of a scan that was not located


@dataclass(frozen=True)
class KnnMethod:
    """One way to locate a scan.

    ``k`` neighbours; ``weighted``: each by the inverse of its RSS distance (W-KNN) instead of
    equally; ``average_places``: the radio map holds one averaged fingerprint per surveyed place
    (seed 001's map) instead of every sample; ``floor_detection``: the floor is the one most
    neighbours are on and only those place the scan (without it the floor is still the majority's,
    but every neighbour averages into the position, across floors too)."""

    name: str
    k: int
    weighted: bool = False
    average_places: bool = False
    floor_detection: bool = False


@dataclass(frozen=True)
class RadioMap:
    """The fingerprints a method matches against, their RSS filled with ``not_detected_dbm``."""

    fingerprints: Fingerprints
    filled: np.ndarray
    not_detected_dbm: float


@dataclass(frozen=True)
class Locations:
    """Per scan: ``positions`` (N, 2) (NaN when not located), ``floors`` (N,)
    (``NOT_LOCATED_FLOOR`` when not located) and ``known_heard`` (N,), how many access points of
    the radio map the scan heard; a scan that heard none is not located: it carries no evidence,
    and its nearest neighbours would be whichever places hear least."""

    positions: np.ndarray
    floors: np.ndarray
    known_heard: np.ndarray

    @property
    def located(self) -> np.ndarray:
        return self.known_heard > 0


def build_radio_map(survey: Fingerprints, method: KnnMethod, not_detected_dbm: float, place_tolerance_m: float) -> RadioMap:
    """The radio map ``method`` matches against, from the survey samples."""
    fingerprints = averaged(survey, place_tolerance_m, not_detected_dbm) if method.average_places else survey
    return RadioMap(fingerprints, np.nan_to_num(fingerprints.rss, nan=not_detected_dbm), not_detected_dbm)


def _squared_distances(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.clip((a * a).sum(axis=1)[:, None] + (b * b).sum(axis=1)[None] - 2.0 * a @ b.T, 0.0, None)


def locate(radio_map: RadioMap, rss: np.ndarray, method: KnnMethod) -> Locations:
    """Locate scans ``rss`` (M, A) dBm, NaN where not heard, in the radio map's access point columns."""
    known_heard = np.isfinite(rss).sum(axis=1)
    distances = np.sqrt(_squared_distances(np.nan_to_num(rss, nan=radio_map.not_detected_dbm), radio_map.filled))
    k = min(method.k, len(radio_map.filled))
    nearest = np.argsort(distances, axis=1, kind="stable")[:, :k]
    floors = radio_map.fingerprints.floors[nearest]
    weights = 1.0 / (np.take_along_axis(distances, nearest, axis=1) + 1e-6) if method.weighted else np.ones(nearest.shape)
    floor = np.array([_majority(f, w) for f, w in zip(floors, weights)], dtype=int)
    if method.floor_detection:
        weights = np.where(floors == floor[:, None], weights, 0.0)
    positions = np.einsum("mk,mkd->md", weights, radio_map.fingerprints.positions[nearest]) / weights.sum(axis=1, keepdims=True)
    located = known_heard > 0
    return Locations(np.where(located[:, None], positions, np.nan), np.where(located, floor, NOT_LOCATED_FLOOR), known_heard)


def _majority(floors: np.ndarray, weights: np.ndarray) -> int:
    """The floor most neighbours are on; a tie goes to the floor with the larger total weight,
    then to the nearest neighbour's."""
    values, counts = np.unique(floors, return_counts=True)
    totals = np.array([weights[floors == v].sum() for v in values])
    best = np.lexsort((totals, counts))[-1]
    return int(values[best])
