"""Seed 003's marker map (section 3.2.2): an adjacency graph keyed by marker id, its 2-D grid, and
the metric map beside it.

Two markers tracked in the same frame are linked north, east, south or west of each other by their
yaw-compensated offset (Eq. 1). Each link carries a quality that falls with the tracking distance
(false detections grow with it), and a link of higher quality overwrites one of lower. The grid is
laid out from the first marker by walking the links. The metric map holds each marker's pose
(x, y, theta) on the floor in the frame of the first marker mapped; new markers are chained from
mapped ones in the same frame (where their corners' rays meet the floor, with the camera pose
solved from every mapped marker's corners at once: ``evp.markers.floor``) and the whole map is
refined by the pose graph now and then.

Bad input is handled here and logged in ``events``: one id seen twice in a frame, or seen far from
where the map has it while other markers agree on the camera, is a duplicate and is not used; a new
id must be seen in ``min_frames`` consecutive frames before it is mapped (one frame at the image
edge is noise).
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field

import numpy as np

from evp.config import MarkerSettings
from evp.markers.detection import MarkerObservation, yaw_compensate
from evp.markers.floor import camera_over_floor, camera_pose_2d, floor_points, marker_pose_from_corners
from evp.markers.planar import camera_over_marker, compose, inverse
from evp.markers.pose_graph import refine_poses

DIRECTIONS = {"north": (0, 1), "east": (1, 0), "south": (0, -1), "west": (-1, 0)}
OPPOSITE = {"north": "south", "south": "north", "east": "west", "west": "east"}
MAX_OFF_AXIS = 0.35  # an offset more than this share off its axis is a diagonal: no N/E/S/W link
NEIGHBOUR_PITCHES = 1.5  # a link joins markers at most this many grid pitches apart (the nearest)


@dataclass(frozen=True)
class Adjacency:
    neighbour: int
    quality: float


@dataclass(frozen=True)
class MapEvent:
    time_s: float
    kind: str
    detail: str


@dataclass(frozen=True)
class Localisation:
    """The camera over the map from one frame: (x, y, yaw of the body's forward axis) in the map
    frame, the height above the floor, and the markers it used."""

    pose: np.ndarray
    height_m: float
    marker_ids: tuple[int, ...]
    camera_by_marker: dict[int, np.ndarray]  # the camera (x, y) as each marker alone places it


@dataclass
class MarkerMap:
    settings: MarkerSettings
    min_frames: int = 2
    poses: dict[int, np.ndarray] = field(default_factory=dict)
    adjacency: dict[int, dict[str, Adjacency]] = field(default_factory=dict)
    edges: dict[tuple[int, int], tuple[np.ndarray, float]] = field(default_factory=dict)
    events: list[MapEvent] = field(default_factory=list)
    root: int | None = None
    pitch_m: float = np.inf
    _candidates: dict[int, int] = field(default_factory=dict)
    _edge_sums: dict[tuple[int, int], np.ndarray] = field(default_factory=dict)
    _new_markers: int = 0
    _rejected: set[int] = field(default_factory=set)

    def __len__(self) -> int:
        return len(self.poses)

    def log(self, time_s: float, kind: str, detail: str) -> None:
        self.events.append(MapEvent(time_s, kind, detail))

    def update(self, time_s: float, observations: list[MarkerObservation], expected_xy: np.ndarray | None = None) -> Localisation | None:
        """Map one frame's markers and localise the camera from the mapped ones (None if none).
        ``expected_xy`` is where the camera's own motion puts it (the autopilot's prediction from
        the last frame): a single mapped marker that puts the camera farther than
        ``lone_marker_tolerance_m`` from there has no other marker to outvote it, and is a second
        marker with its id (or a misread) as surely as one the others disagree with."""
        observations = self._without_repeated_ids(time_s, observations)
        if self.root is None and observations:
            nearest = min(observations, key=lambda o: o.distance_m)
            self.root = nearest.marker_id
            self.poses[self.root] = np.zeros(3)
            self.adjacency[self.root] = {}
            self.log(time_s, "map_started", f"marker {self.root} is the map's origin")
        over = {o.marker_id: camera_over_marker(o) for o in observations}
        known = self._without_duplicates(time_s, [i for i in over if i in self.poses], over)
        if expected_xy is not None and len(known) == 1:
            known = self._near_expected(time_s, known[0], compose(self.poses[known[0]], over[known[0]])[:2], expected_xy)
        usable = [o for o in observations if o.marker_id not in self._rejected]
        solved = camera_over_floor([o for o in usable if o.marker_id in known], self.poses, self.settings.marker_size_m)
        if solved is None:
            self._forget_candidates(time_s, set())
            return None
        R_cam_floor, t_cam_floor = solved
        placed = {o.marker_id: marker_pose_from_corners(floor_points(R_cam_floor, t_cam_floor, o.rays)) for o in usable}
        placed = {i: pose for i, pose in placed.items() if np.all(np.isfinite(pose))}  # a ray along the floor meets it nowhere
        distance = {o.marker_id: o.distance_m for o in usable}
        self._link(placed, distance)
        self._add_new(time_s, [i for i in placed if i not in self.poses], placed)
        if self._new_markers >= self.settings.refine_every_markers and len(self.poses) > 2:
            self.refine()
        camera, height = camera_pose_2d(R_cam_floor, t_cam_floor)
        by_marker = {i: compose(self.poses[i], compose(inverse(placed[i]), camera))[:2] for i in known}
        return Localisation(camera, height, tuple(known), by_marker)

    def _without_repeated_ids(self, time_s: float, observations: list[MarkerObservation]) -> list[MarkerObservation]:
        counts: dict[int, int] = {}
        for o in observations:
            counts[o.marker_id] = counts.get(o.marker_id, 0) + 1
        repeated = sorted(i for i, n in counts.items() if n > 1)
        if repeated:
            self.log(time_s, "duplicate_id", f"ids {repeated} seen twice in one frame: not used")
        return [o for o in observations if counts[o.marker_id] == 1]

    def _without_duplicates(self, time_s: float, known: list[int], over: dict[int, np.ndarray]) -> list[int]:
        """Mapped markers whose camera positions agree; one far from the others' consensus is a
        second marker with the same id (or a misread): rejected and logged."""
        self._rejected = set()
        if len(known) < 2:
            return known
        cameras = {i: compose(self.poses[i], over[i])[:2] for i in known}
        centre = np.median(np.array(list(cameras.values())), axis=0)
        keep = [i for i in known if np.linalg.norm(cameras[i] - centre) <= self.settings.duplicate_tolerance_m]
        if len(keep) < len(known) / 2:  # no consensus: trust none of them this frame
            self.log(time_s, "inconsistent_markers", f"markers {sorted(known)} disagree on the camera position: frame not used")
            self._rejected = set(known)
            return []
        for i in set(known) - set(keep):
            self._rejected.add(i)
            self.log(time_s, "duplicate_id", f"marker {i} seen {np.linalg.norm(cameras[i] - centre):.2f} m from its mapped place: not used")
        return keep

    def _near_expected(self, time_s: float, marker_id: int, camera_xy: np.ndarray, expected_xy: np.ndarray) -> list[int]:
        jump = float(np.linalg.norm(camera_xy - expected_xy))
        if jump <= self.settings.lone_marker_tolerance_m:
            return [marker_id]
        self._rejected.add(marker_id)
        self.log(
            time_s, "duplicate_id", f"marker {marker_id}, the only mapped one in view, puts the camera {jump:.2f} m from where its motion has it: not used"
        )
        return []

    def _forget_candidates(self, time_s: float, seen_now: set[int]) -> None:
        """New markers not seen again in the next frame are not mapped (a marker at the image's
        edge for one frame, a misread id): logged, so the operator knows why a marker is missing."""
        for i, frames in self._candidates.items():
            if i not in seen_now:
                self.log(time_s, "unconfirmed_marker", f"marker {i} seen in {frames} frame(s) in a row, fewer than {self.min_frames}: not mapped")
        self._candidates = {i: n for i, n in self._candidates.items() if i in seen_now}

    def _add_new(self, time_s: float, new: list[int], placed: dict[int, np.ndarray]) -> None:
        self._forget_candidates(time_s, set(new))
        for i in new:
            self._candidates[i] = self._candidates.get(i, 0) + 1
            if self._candidates[i] < self.min_frames:
                continue
            self.poses[i] = placed[i]
            self.adjacency.setdefault(i, {})
            del self._candidates[i]
            self._new_markers += 1
            self.log(time_s, "marker_mapped", f"marker {i} at ({self.poses[i][0]:.3f}, {self.poses[i][1]:.3f}) m")

    def quality(self, distance_m: float) -> float:
        """Seed 003: the farther the camera, the lower the quality of what it links."""
        return max(0.0, 1.0 - distance_m / self.settings.max_quality_distance_m)

    def _link(self, placed: dict[int, np.ndarray], distance: dict[int, float]) -> None:
        """Links and relative poses of every pair of markers placed in this frame."""
        ids = list(placed)
        for a_index, a in enumerate(ids):
            for b in ids[a_index + 1 :]:
                quality = self.quality(max(distance[a], distance[b]))
                self._accumulate(a, b, compose(inverse(placed[a]), placed[b]), quality)
                offset = placed[b][:2] - placed[a][:2]
                length = float(np.linalg.norm(offset))
                if length > self.settings.marker_size_m and a in self.poses and b in self.poses:  # mapped pairs only: a new one may be misplaced
                    self.pitch_m = min(self.pitch_m, length)
                along_a = yaw_compensate(np.array([offset[0], offset[1], 0.0]), placed[a][2])[0, :2]  # Eq. 1: in marker a's axes
                direction = _direction(along_a, self.pitch_m)
                if direction is None:
                    continue
                for here, there, way in ((a, b, direction), (b, a, OPPOSITE[direction])):
                    links = self.adjacency.setdefault(here, {})
                    if way not in links or links[way].quality < quality:
                        links[way] = Adjacency(there, quality)

    def _accumulate(self, a: int, b: int, relative: np.ndarray, weight: float) -> None:
        """Quality-weighted running mean of the relative pose of b in a (angle as a unit vector)."""
        key, relative = ((a, b), relative) if a < b else ((b, a), inverse(relative))
        sums = self._edge_sums.setdefault(key, np.zeros(5))
        sums += weight * np.array([relative[0], relative[1], np.cos(relative[2]), np.sin(relative[2]), 1.0])
        if sums[4] > 0:
            self.edges[key] = (np.array([sums[0] / sums[4], sums[1] / sums[4], np.arctan2(sums[3], sums[2])]), float(sums[4]))

    def refine(self) -> None:
        """Re-solve every marker pose from all the relative poses seen (the pose graph)."""
        if self.root is not None:
            self.poses = refine_poses(self.poses, self.edges, self.root)
        self._new_markers = 0

    def grid(self) -> dict[int, tuple[int, int]]:
        """The 2-D grid (column east, row north) from the links, walked from the first marker;
        a marker whose cell is taken keeps the first one found (logged once as a conflict)."""
        if self.root is None:
            return {}
        cells = {self.root: (0, 0)}
        taken = {(0, 0): self.root}
        queue = deque([self.root])
        while queue:
            here = queue.popleft()
            for way, link in sorted(self.adjacency.get(here, {}).items()):
                if link.neighbour in cells or link.neighbour not in self.poses:
                    continue
                step = DIRECTIONS[way]
                cell = (cells[here][0] + step[0], cells[here][1] + step[1])
                if cell in taken:
                    continue
                cells[link.neighbour] = cell
                taken[cell] = link.neighbour
                queue.append(link.neighbour)
        return cells


def _direction(offset: np.ndarray, pitch_m: float) -> str | None:
    """North/east/south/west of an offset in the first marker's axes, or None (diagonal, or
    farther than the nearest neighbour)."""
    length = float(np.linalg.norm(offset))
    if not np.isfinite(pitch_m) or length > NEIGHBOUR_PITCHES * pitch_m:
        return None
    if abs(offset[0]) >= abs(offset[1]):
        return ("east" if offset[0] > 0 else "west") if abs(offset[1]) <= MAX_OFF_AXIS * length else None
    return ("north" if offset[1] > 0 else "south") if abs(offset[0]) <= MAX_OFF_AXIS * length else None
