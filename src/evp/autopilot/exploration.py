"""Seed 003, section 3.2.3: where to explore next.

The open frontier is every grid direction of a mapped marker where the map has no neighbour and
the camera has not yet looked: its expected place (one grid pitch away, in the marker's axes) is
the next navigation target, nearest first. A place the camera has passed over (within
``close_radius_m``) without finding a marker there is closed: it lies beyond the map's edge.
"""

from __future__ import annotations

import numpy as np

from evp.markers.marker_map import DIRECTIONS, MarkerMap
from evp.markers.planar import compose


def frontier(marker_map: MarkerMap, closed: set[tuple[int, str]]) -> dict[tuple[int, str], np.ndarray]:
    """(marker id, direction) -> expected (x, y) of the missing neighbour, for the open ones."""
    if not np.isfinite(marker_map.pitch_m) or not marker_map.poses:
        return {}
    ids = list(marker_map.poses)
    mapped = np.array([marker_map.poses[i][:2] for i in ids])
    places = {}
    for marker_id in ids:
        links = marker_map.adjacency.get(marker_id, {})
        for way, (dx, dy) in DIRECTIONS.items():
            if way in links or (marker_id, way) in closed:
                continue
            place = compose(marker_map.poses[marker_id], np.array([dx * marker_map.pitch_m, dy * marker_map.pitch_m, 0.0]))[:2]
            if np.min(np.linalg.norm(mapped - place, axis=1)) < marker_map.pitch_m / 2:  # mapped, only not linked
                continue
            places[(marker_id, way)] = place
    return places


def close_passed(places: dict[tuple[int, str], np.ndarray], camera_xy: np.ndarray, close_radius_m: float) -> list[tuple[int, str]]:
    """The open places the camera is now over: seen, and empty (else the map would hold them)."""
    return [key for key, place in places.items() if np.linalg.norm(place - camera_xy) <= close_radius_m]


def nearest(places: dict[tuple[int, str], np.ndarray], camera_xy: np.ndarray) -> tuple[tuple[int, str], np.ndarray] | None:
    if not places:
        return None
    key = min(places, key=lambda k: float(np.linalg.norm(places[k] - camera_xy)))
    return key, places[key]
