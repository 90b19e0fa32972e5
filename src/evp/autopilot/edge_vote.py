"""Seed 003, section 3.2.6: which way to steer back after flying off the marker map.

Three clues each vote for the direction the vehicle left by (east/west, north/south), weighted by
its quality Q_i and reliability W_i (Eq. 4): p, where the camera was around the last marker it
tracked; m, where that marker lies in the map (its quality grows with the map); d, the drift just
before the exit. The counter-steer is the opposite of the winner on each axis. Unlike the paper's
quadrant rule (Eq. 2), p votes on both axes by the cosine and sine of its angle, and an axis whose
winning vote is close to the other axis's also steers, so a diagonal exit at a corner is answered
with a diagonal counter-steer (the paper's 6 % of failures were lateral moves along the edge).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

SECOND_AXIS_SHARE = 0.35  # the weaker axis steers too when its vote is at least this share of the stronger
MAP_QUALITY_MARKERS = 20  # m's quality reaches 1 once the map holds this many markers
DRIFT_QUALITY_SPEED_M_S = 0.2  # d's quality reaches 1 at this drift speed


@dataclass(frozen=True)
class EdgeVote:
    """The summed votes (east, west, north, south) and the unit counter-steer direction (map frame)."""

    votes: np.ndarray
    counter_steer: np.ndarray


def _decisions(direction: np.ndarray) -> np.ndarray:
    """(east, west, north, south) decisions of a direction: its positive and negative parts."""
    x, y = direction
    return np.array([max(x, 0.0), max(-x, 0.0), max(y, 0.0), max(-y, 0.0)])


def counter_steer(
    exit_position: np.ndarray,
    last_marker: np.ndarray,
    map_centre: np.ndarray,
    map_half_extent: np.ndarray,
    mapped_markers: int,
    drift_velocity: np.ndarray,
    pitch_m: float,
    weights: tuple[float, float, float],
) -> EdgeVote:
    """Eq. 4 over the clues p, m and d (positions in the map frame, metres)."""
    beyond = exit_position - last_marker
    distance = float(np.linalg.norm(beyond))
    p = beyond / distance if distance > 1e-9 else np.zeros(2)
    q_p = min(1.0, distance / max(pitch_m, 1e-3))
    m = np.clip((last_marker - map_centre) / np.maximum(map_half_extent, 1e-3), -1.0, 1.0)
    q_m = min(1.0, mapped_markers / MAP_QUALITY_MARKERS)
    speed = float(np.linalg.norm(drift_velocity))
    d = drift_velocity / speed if speed > 1e-9 else np.zeros(2)
    q_d = min(1.0, speed / DRIFT_QUALITY_SPEED_M_S)
    w_p, w_m, w_d = weights
    votes = _decisions(p) * q_p * w_p + _decisions(m) * q_m * w_m + _decisions(d) * q_d * w_d
    x = votes[0] - votes[1]
    y = votes[2] - votes[3]
    strongest = max(abs(x), abs(y))
    if strongest < 1e-9:  # no clue at all: head for the map's centre
        back = map_centre - exit_position
        norm = float(np.linalg.norm(back))
        return EdgeVote(votes, back / norm if norm > 1e-9 else np.zeros(2))
    exit_direction = np.array([np.sign(x) if abs(x) >= SECOND_AXIS_SHARE * strongest else 0.0, np.sign(y) if abs(y) >= SECOND_AXIS_SHARE * strongest else 0.0])
    return EdgeVote(votes, -exit_direction / np.linalg.norm(exit_direction))
