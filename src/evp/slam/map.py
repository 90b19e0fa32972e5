"""The SLAM map: keyframes, map points, the covisibility graph; to and from flat arrays (its
files are in ``evp.io.map_files``).

Poses are stored as ``T_cw`` (world to camera), the form projection needs. All mutation goes
through :class:`Map` methods; callers hold ``Map.lock`` while tracking reads and mapping writes
(a no-op unless the runtime maps in another thread and lends a real lock).
"""

from __future__ import annotations

from collections import Counter
from contextlib import AbstractContextManager, nullcontext
from dataclasses import dataclass, field
from itertools import chain

import numpy as np

from evp.geometry.transforms import se3_inverse
from evp.slam.keyframe_database import KeyframeDatabase
from evp.vision.matching import hamming_pairs
from evp.vision.orb import Features
from evp.vision.vocabulary import BowVector


@dataclass
class KeyFrame:
    id: int
    timestamp: float
    T_cw: np.ndarray
    features: Features
    point_ids: np.ndarray  # (N,) map point id per feature, -1 where none
    bow: BowVector  # bag-of-words vector of its descriptors (place recognition)
    covisible: Counter = field(default_factory=Counter)  # keyframe id -> shared points
    centre: np.ndarray = field(init=False)  # camera centre in the world, kept in step with T_cw

    def __post_init__(self) -> None:
        self.set_pose(self.T_cw)

    def set_pose(self, T_cw: np.ndarray) -> None:
        self.T_cw = T_cw
        self.centre = -T_cw[:3, :3].T @ T_cw[:3, 3]

    def best_covisible(self, count: int, min_weight: int = 1) -> list[int]:
        return [k for k, w in self.covisible.most_common(count) if w >= min_weight]


class PointStore:
    """The per-point numbers tracking reads every frame, as arrays indexed by point id, so that
    thousands of points are gathered with one fancy index instead of a Python loop."""

    COLUMNS = ("position", "normal", "min_distance", "max_distance", "descriptor", "alive")

    def __init__(self, capacity: int = 1024):
        self.position = np.zeros((capacity, 3))
        self.normal = np.zeros((capacity, 3))
        self.min_distance = np.zeros(capacity)
        self.max_distance = np.full(capacity, np.inf)
        self.descriptor = np.zeros((capacity, 32), np.uint8)
        self.alive = np.zeros(capacity, bool)  # the id names a point of the map

    def reserve(self, point_id: int) -> None:
        """Room for ``point_id`` (arrays double; views taken before do not follow)."""
        capacity = len(self.position)
        if point_id < capacity:
            return
        grown = max(2 * capacity, point_id + 1)
        for name in self.COLUMNS:
            old = getattr(self, name)
            new = np.zeros((grown, *old.shape[1:]), old.dtype)
            new[:capacity] = old
            setattr(self, name, new)
        self.max_distance[capacity:] = np.inf


class _StoreColumn:
    """A MapPoint attribute read from and written to its row of one PointStore array (a view for
    vectors, a float for scalars)."""

    def __init__(self, name: str):
        self.name = name

    def __get__(self, point: MapPoint, owner: type) -> np.ndarray | float:
        value = getattr(point._store, self.name)[point.id]
        return value if np.ndim(value) else float(value)

    def __set__(self, point: MapPoint, value) -> None:
        getattr(point._store, self.name)[point.id] = value


class MapPoint:
    """A 3-D point and its observations. Its geometry lives in the map's :class:`PointStore`:
    ``position``, ``normal`` and ``descriptor`` are views of store rows (do not keep one across
    :meth:`Map.add_point`, which may grow the store)."""

    __slots__ = ("id", "first_kf", "observations", "visible", "found", "_store")

    position = _StoreColumn("position")
    normal = _StoreColumn("normal")  # mean viewing direction (unit)
    descriptor = _StoreColumn("descriptor")
    min_distance = _StoreColumn("min_distance")
    max_distance = _StoreColumn("max_distance")

    def __init__(self, store: PointStore, point_id: int, position: np.ndarray, descriptor: np.ndarray, first_kf: int):
        self._store = store
        self.id = point_id
        self.first_kf = first_kf
        self.observations: dict[int, int] = {}  # keyframe id -> feature index
        self.visible = 1  # frames in whose frustum it was
        self.found = 1  # frames that matched it
        store.reserve(point_id)
        store.position[point_id] = position
        store.descriptor[point_id] = descriptor  # the most representative of its observations
        store.normal[point_id] = 0.0
        store.min_distance[point_id], store.max_distance[point_id] = 0.0, np.inf
        store.alive[point_id] = True

    @property
    def found_ratio(self) -> float:
        return self.found / max(1, self.visible)


class Map:
    """``lock``: what tracking and mapping hold while they read and change the map; nothing to
    hold by default (one thread), a re-entrant lock when the runtime maps in a thread of its own."""

    def __init__(self, lock: AbstractContextManager | None = None) -> None:
        self.keyframes: dict[int, KeyFrame] = {}
        self.points: dict[int, MapPoint] = {}
        self.store = PointStore()
        self.database = KeyframeDatabase()  # the keyframes' bag-of-words vectors, kept in step
        self.lock = lock if lock is not None else nullcontext()
        self._next_kf = 0
        self._next_point = 0
        # culled keyframe id -> (parent keyframe id, T_kf_parent): frames that referenced a culled
        # keyframe still find their pose through its parent
        self.removed_parents: dict[int, tuple[int, np.ndarray]] = {}

    # --- creation -----------------------------------------------------------------------

    def add_keyframe(self, timestamp: float, T_cw: np.ndarray, features: Features, bow: BowVector) -> KeyFrame:
        kf = KeyFrame(self._next_kf, timestamp, T_cw.copy(), features, np.full(len(features), -1, int), bow)
        self._next_kf += 1
        self.keyframes[kf.id] = kf
        self.database.add(kf.id, bow)
        return kf

    def add_point(self, position: np.ndarray, descriptor: np.ndarray, first_kf: int) -> MapPoint:
        point = MapPoint(self.store, self._next_point, position, descriptor, first_kf)
        self._next_point += 1
        self.points[point.id] = point
        return point

    def add_observation(self, point: MapPoint, kf: KeyFrame, index: int) -> None:
        old = kf.point_ids[index]
        if old >= 0 and old != point.id and old in self.points:
            self.points[old].observations.pop(kf.id, None)
        kf.point_ids[index] = point.id
        point.observations[kf.id] = index

    # --- removal ------------------------------------------------------------------------

    def remove_observation(self, point: MapPoint, kf_id: int) -> None:
        index = point.observations.pop(kf_id, None)
        kf = self.keyframes.get(kf_id)
        if index is not None and kf is not None and kf.point_ids[index] == point.id:
            kf.point_ids[index] = -1
        if len(point.observations) < 2:
            self.remove_point(point.id)

    def remove_point(self, point_id: int) -> None:
        point = self.points.pop(point_id, None)
        if point is None:
            return
        self.store.alive[point_id] = False
        for kf_id, index in point.observations.items():
            kf = self.keyframes.get(kf_id)
            if kf is not None and kf.point_ids[index] == point_id:
                kf.point_ids[index] = -1

    def remove_all_points(self) -> None:
        self.points.clear()
        self.store.alive[:] = False

    def remove_keyframe(self, kf_id: int) -> None:
        kf = self.keyframes.pop(kf_id)
        self.database.remove(kf_id)
        parent = next((k for k in kf.best_covisible(len(kf.covisible)) if k in self.keyframes), None)
        if parent is not None:
            self.removed_parents[kf_id] = (parent, kf.T_cw @ se3_inverse(self.keyframes[parent].T_cw))
        for point_id in kf.point_ids[kf.point_ids >= 0]:
            point = self.points.get(int(point_id))
            if point is not None:
                point.observations.pop(kf_id, None)
                if len(point.observations) < 2:
                    self.remove_point(point.id)
        for other in kf.covisible:
            if other in self.keyframes:
                self.keyframes[other].covisible.pop(kf_id, None)

    def replace_point(self, old_id: int, new_id: int) -> None:
        """Merge a duplicate: every observation of ``old_id`` moves to ``new_id``."""
        old, new = self.points.get(old_id), self.points.get(new_id)
        if old is None or new is None or old_id == new_id:
            return
        for kf_id, index in list(old.observations.items()):
            kf = self.keyframes.get(kf_id)
            if kf is None:
                continue
            if kf_id in new.observations:
                kf.point_ids[index] = -1
            else:
                self.add_observation(new, kf, index)
        new.visible += old.visible
        new.found += old.found
        old.observations.clear()
        self.points.pop(old_id, None)
        self.store.alive[old_id] = False

    # --- derived state ------------------------------------------------------------------

    def observation_table(self, point_ids: list[int]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Every observation of ``point_ids`` by a live keyframe, point by point: (position in
        ``point_ids``, keyframe id, feature index) as three integer arrays. The one walk over the
        observation dictionaries that map-wide computations need (read by ``np.fromiter``, not
        a Python loop); the rest is array work."""
        observations = [self.points[point_id].observations for point_id in point_ids]
        counts = np.fromiter(map(len, observations), np.int64, len(observations))
        total = int(counts.sum())
        kf_ids = np.fromiter(chain.from_iterable(observations), np.int64, total)
        indices = np.fromiter(chain.from_iterable(o.values() for o in observations), np.int64, total)
        rows = np.repeat(np.arange(len(point_ids)), counts)
        alive = np.fromiter(self.keyframes, np.int64, len(self.keyframes))
        live = np.zeros(max(kf_ids.max(initial=-1), alive.max(initial=-1)) + 1, bool)
        live[alive] = True
        keep = live[kf_ids]
        return rows[keep], kf_ids[keep], indices[keep]

    def gather_features(self, kf_ids: np.ndarray, indices: np.ndarray, attribute: str) -> np.ndarray:
        """``features.<attribute>[index]`` of each (keyframe, feature index) pair: one fancy
        index per keyframe instead of one per observation."""
        order = np.argsort(kf_ids, kind="stable")
        unique, starts = np.unique(kf_ids[order], return_index=True)
        bounds = np.r_[starts, len(order)]
        out = None
        for u, kf_id in enumerate(unique.tolist()):
            column = getattr(self.keyframes[kf_id].features, attribute)
            if out is None:
                out = np.zeros((len(kf_ids), *column.shape[1:]), column.dtype)
            rows = order[bounds[u] : bounds[u + 1]]
            out[rows] = column[indices[rows]]
        return out if out is not None else np.zeros(0)

    def gather_lens_jacobians(self, kf_ids: np.ndarray, indices: np.ndarray) -> np.ndarray | None:
        """``features.lens_jacobian[index]`` of each (keyframe, feature index) pair; None when no
        keyframe among them has one (a lens without distortion), identity for a keyframe without
        one among others that have (read from a map file written before they were kept)."""
        unique = np.unique(kf_ids).tolist()
        if all(self.keyframes[k].features.lens_jacobian is None for k in unique):
            return None
        out = np.repeat(np.eye(2)[None], len(kf_ids), axis=0)
        for kf_id in unique:
            column = self.keyframes[kf_id].features.lens_jacobian
            if column is not None:
                rows = np.flatnonzero(kf_ids == kf_id)
                out[rows] = column[indices[rows]]
        return out

    def refresh_points(self, point_ids: list[int], scale_factors: np.ndarray, descriptor: bool = True) -> None:
        """Mean viewing direction and scale-invariance distance range of points, from the keyframes
        observing them (the range from the first keyframe's view and octave); with
        ``descriptor``, also each one's representative descriptor: of its observations'
        descriptors, the one with the least median Hamming distance to the others (points with as
        many observations go together)."""
        rows, kf_ids, indices = self.observation_table(point_ids)
        if len(rows) == 0:
            return
        self._update_geometry(point_ids, rows, kf_ids, indices, scale_factors)
        if not descriptor:
            return
        descriptors = self.gather_features(kf_ids, indices, "descriptors")
        counts = np.bincount(rows, minlength=len(point_ids))
        starts = np.r_[0, np.cumsum(counts)[:-1]]
        ids = np.asarray(point_ids, int)
        for count in np.unique(counts[counts > 0]).tolist():
            group = np.flatnonzero(counts == count)
            stacks = starts[group][:, None] + np.arange(count)  # (points, count) rows of descriptors
            best = np.zeros(len(group), int)
            if count > 2:
                pairs = (len(group), count, count)
                a = np.broadcast_to(stacks[:, :, None], pairs).ravel()
                b = np.broadcast_to(stacks[:, None, :], pairs).ravel()
                distances = hamming_pairs(descriptors, descriptors, a, b).reshape(pairs)
                middle = np.partition(distances, [(count - 1) // 2, count // 2], axis=2)  # np.median's two middles
                best = np.argmin(middle[:, :, (count - 1) // 2] + middle[:, :, count // 2], axis=1)
            self.store.descriptor[ids[group]] = descriptors[stacks[np.arange(len(group)), best]]

    def _update_geometry(self, point_ids: list[int], rows: np.ndarray, kf_ids: np.ndarray, indices: np.ndarray, scale_factors: np.ndarray) -> None:
        ids = np.asarray(point_ids, int)
        involved = np.unique(kf_ids)
        centres = np.array([self.keyframes[k].centre for k in involved.tolist()])[np.searchsorted(involved, kf_ids)]
        positions = self.store.position[ids]
        rays = positions[rows] - centres
        rays /= np.maximum(np.sqrt(np.einsum("ij,ij->i", rays, rays)), 1e-12)[:, None]
        normal = np.stack([np.bincount(rows, rays[:, axis], len(ids)) for axis in range(3)], axis=1)
        # the reference view: the point's first keyframe's when it still sees it, else the first
        observed, first = np.unique(rows, return_index=True)
        first_kf = np.array([self.points[p].first_kf for p in point_ids])
        by_first = np.flatnonzero(kf_ids == first_kf[rows])
        reference = np.zeros(len(ids), int)
        reference[observed] = first
        reference[rows[by_first]] = by_first
        reference = reference[observed]
        normal = normal[observed]
        self.store.normal[ids[observed]] = normal / np.maximum(np.linalg.norm(normal, axis=1), 1e-12)[:, None]
        octaves = self.gather_features(kf_ids[reference], indices[reference], "octave")
        max_distance = np.linalg.norm(positions[observed] - centres[reference], axis=1) * scale_factors[octaves]
        self.store.max_distance[ids[observed]] = max_distance
        self.store.min_distance[ids[observed]] = max_distance / scale_factors[-1]

    def update_covisibility(self, kf: KeyFrame) -> None:
        """Recount the points ``kf`` shares with every other keyframe (both directions)."""
        shared: Counter = Counter()
        for point_id in kf.point_ids[kf.point_ids >= 0]:
            point = self.points.get(int(point_id))
            if point is None:
                continue
            shared.update(k for k in point.observations if k != kf.id)
        for other_id in list(kf.covisible):
            if other_id not in shared and other_id in self.keyframes:
                self.keyframes[other_id].covisible.pop(kf.id, None)
        kf.covisible = shared
        for other_id, weight in shared.items():
            if other_id in self.keyframes:
                self.keyframes[other_id].covisible[kf.id] = weight

    def rows_with_points(self, point_ids: np.ndarray) -> np.ndarray:
        """Rows of a per-feature point-id array (-1 where none) that name a live point (mapping
        may have culled some since the array was filled)."""
        rows = np.flatnonzero(point_ids >= 0)
        return rows[self.store.alive[point_ids[rows]]]

    @property
    def origin_id(self) -> int | None:
        """The map's first keyframe: it anchors the map (never culled, fixed in adjustments), so
        it keeps the lowest id while the map lives."""
        return min(self.keyframes, default=None)

    def median_depth(self, kf: KeyFrame) -> float:
        """Median depth (map units) of the live points ``kf`` sees; NaN when it sees none (a
        keyframe not yet mapped, or every point culled)."""
        ids = kf.point_ids[self.rows_with_points(kf.point_ids)]
        if len(ids) == 0:
            return float("nan")
        depth = self.store.position[ids] @ kf.T_cw[2, :3] + kf.T_cw[2, 3]
        return float(np.median(depth))

    def point_array(self) -> tuple[np.ndarray, np.ndarray]:
        ids = np.array(sorted(self.points), dtype=int)
        return ids, self.store.position[ids].copy()

    # --- trajectory and arrays ---------------------------------------------------------

    def keyframe_poses(self) -> tuple[np.ndarray, np.ndarray]:
        """Timestamps and ``T_world_cam`` of the keyframes in time order."""
        kfs = sorted(self.keyframes.values(), key=lambda k: k.timestamp)
        return np.array([k.timestamp for k in kfs]), np.array([se3_inverse(k.T_cw) for k in kfs]).reshape(-1, 4, 4)

    @property
    def id_counters(self) -> tuple[int, int]:
        """The ids the next keyframe and the next point will get (a reloaded map goes on from them)."""
        return self._next_kf, self._next_point

    def to_arrays(self) -> dict[str, np.ndarray]:
        """Everything needed to relocalise against and extend the map later, as flat arrays:
        keyframes in id order with their features and bag-of-words vectors concatenated (and
        their sizes), points in id order. :meth:`from_arrays` rebuilds the map from them."""
        kfs = sorted(self.keyframes.values(), key=lambda k: k.id)
        point_ids, positions = self.point_array()
        arrays = {
            "kf_ids": np.array([k.id for k in kfs], int),
            "kf_timestamps": np.array([k.timestamp for k in kfs]),
            "kf_T_cw": np.array([k.T_cw for k in kfs]).reshape(-1, 4, 4),
            "kf_bow_sizes": np.array([len(k.bow) for k in kfs], int),
            "bow_words": np.concatenate([k.bow.words for k in kfs]) if kfs else np.zeros(0, np.int32),
            "bow_weights": np.concatenate([k.bow.weights for k in kfs]) if kfs else np.zeros(0),
            "kf_sizes": np.array([len(k.features) for k in kfs], int),
            "point_ids": point_ids,
            "point_positions": positions,
            "point_descriptors": self.store.descriptor[point_ids],
            "point_first_kf": np.array([self.points[i].first_kf for i in point_ids], int),
        }
        for name in ("px", "un_px", "normalised", "octave", "angle", "descriptors"):
            arrays[f"feat_{name}"] = np.concatenate([getattr(k.features, name) for k in kfs]) if kfs else np.zeros(0)
        arrays["feat_point_ids"] = np.concatenate([k.point_ids for k in kfs]) if kfs else np.zeros(0, int)
        if kfs and all(k.features.lens_jacobian is not None for k in kfs):
            arrays["feat_lens_jacobian"] = np.concatenate([k.features.lens_jacobian for k in kfs])
        return arrays

    @classmethod
    def from_arrays(cls, data: dict[str, np.ndarray], id_counters: tuple[int, int], scale_factors: np.ndarray) -> Map:
        """The map of :meth:`to_arrays`, with its observations, covisibility graph, place-recognition
        database and point statistics rebuilt; ids go on from ``id_counters``."""
        result = cls()
        offsets = np.r_[0, np.cumsum(data["kf_sizes"])]
        bow_offsets = np.r_[0, np.cumsum(data["kf_bow_sizes"])]
        for row, kf_id in enumerate(data["kf_ids"]):
            a, b = offsets[row], offsets[row + 1]
            bow = BowVector(data["bow_words"][bow_offsets[row] : bow_offsets[row + 1]], data["bow_weights"][bow_offsets[row] : bow_offsets[row + 1]])
            lens_jacobian = data["feat_lens_jacobian"][a:b] if "feat_lens_jacobian" in data else None
            features = Features(*(data[f"feat_{n}"][a:b] for n in ("px", "un_px", "normalised", "octave", "angle", "descriptors")), lens_jacobian)
            kf = KeyFrame(
                int(kf_id),
                float(data["kf_timestamps"][row]),
                data["kf_T_cw"][row],
                features,
                data["feat_point_ids"][a:b].astype(int),
                bow,
            )
            result.keyframes[kf.id] = kf
            result.database.add(kf.id, bow)
        for row, point_id in enumerate(data["point_ids"]):
            result.points[int(point_id)] = MapPoint(
                result.store, int(point_id), data["point_positions"][row], data["point_descriptors"][row], int(data["point_first_kf"][row])
            )
        for kf in result.keyframes.values():
            for index in np.flatnonzero(kf.point_ids >= 0):
                point = result.points.get(int(kf.point_ids[index]))
                if point is None:
                    kf.point_ids[index] = -1
                else:
                    point.observations[kf.id] = int(index)
        for kf in result.keyframes.values():
            result.update_covisibility(kf)
        result.refresh_points(list(result.points), scale_factors)
        result._next_kf, result._next_point = id_counters
        return result
