"""Local mapping (ORB-SLAM's LocalMapping): for each new keyframe, register its observations,
cull doubtful recent points, triangulate new points with covisible keyframes, fuse duplicates,
run local bundle adjustment, cull redundant keyframes, then look for a loop (loop_closing.py).

:class:`LocalMapper` does the work for one keyframe in steps (:meth:`LocalMapper.insert`, then
:meth:`LocalMapper.refine`); :class:`InlineMapping` runs them in the tracking thread, and
evp.runtime's mapping worker in a thread of its own, fed by a keyframe queue (both are a
:class:`Mapping`). The bundle adjustment solves on a snapshot without the map lock, so tracking
goes on meanwhile.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from evp.config import SlamSettings
from evp.geometry.epipolar_band import epipolar_pairs
from evp.geometry.two_view import check_points, triangulate
from evp.optim.bundle_adjustment import BundleProblem
from evp.optim.reprojection import CHI2_1DOF
from evp.slam.adjustment import InlineAdjustment
from evp.slam.loop_closing import LoopCloser
from evp.slam.map import KeyFrame, Map
from evp.slam.map_adjustment import apply_solution, whole_map_problem, window_problem
from evp.slam.point_fusion import fuse_points
from evp.slam.projection import undistorted_bounds
from evp.vision.matching import TH_LOW, best_unique_pairs, hamming_pairs, rotation_consistent
from evp.vision.orb import OrbExtractor, window_stretch

# A keyframe that tracked fewer map points than this share of its keypoints is starved (fast
# forward motion: most of the view is new each keyframe, and the points near the focus of
# expansion or far away gain parallax slowly). Its new points take ORB-SLAM's 1.1 degrees of
# parallax instead of slam.new_point_min_parallax_deg: a thin map's need for points outweighs
# their depth precision, while a well-tracked keyframe (hovering, the circle) keeps the stricter
# limit that stopped the live circle's drift.
STARVED_SHARE = 0.1
STARVED_MIN_PARALLAX_DEG = 1.1


@dataclass
class NewKeyFrame:
    keyframe: KeyFrame
    matched_points: np.ndarray  # (N,) map point id per feature at tracking time, -1 where none


class LocalMapper:
    """``adjuster`` solves the bundle adjustments (in this thread by default); whoever schedules the
    mapper may set ``keyframes_waiting`` (newer keyframes queued: skip fusion and adjustment for
    this one, as ORB-SLAM does) and ``step_done`` (called after each step under the map lock)."""

    def __init__(self, slam_map: Map, extractor: OrbExtractor, settings: SlamSettings, adjuster: InlineAdjustment | None = None):
        self.map = slam_map
        self.extractor = extractor
        self.settings = settings
        self.K = extractor.camera.K
        self.bounds = undistorted_bounds(extractor)
        self.adjuster = adjuster or InlineAdjustment()  # tracking may interrupt its local windows
        self.recent_points: list[int] = []
        self._min_parallax_cos = float(np.cos(np.radians(settings.new_point_min_parallax_deg)))
        self._starved_min_parallax_cos = float(np.cos(np.radians(STARVED_MIN_PARALLAX_DEG)))
        self.keyframes_waiting: Callable[[], bool] = lambda: False
        self.step_done: Callable[[], None] = lambda: None
        self.loop_closer = LoopCloser(slam_map, extractor, settings) if settings.loop_closing else None

    def process(self, item: NewKeyFrame) -> None:
        if self.insert(item):
            self.refine(item)

    def insert(self, item: NewKeyFrame) -> bool:
        """The keyframe's observations and new points (what tracking needs soonest); False when
        tracking has since discarded its map."""
        kf = item.keyframe
        with self._locked():
            if not self._in_map(kf):
                return False
            self._register_observations(kf, item.matched_points)
            self.map.update_covisibility(kf)
            self._cull_recent_points(kf)
        self._triangulate_new_points(kf)
        return True

    def refine(self, item: NewKeyFrame) -> None:
        """Fusion, local bundle adjustment and keyframe culling after :meth:`insert`, then loop
        detection."""
        kf = item.keyframe
        if not self.keyframes_waiting():  # behind the camera: the next keyframe first (ORB-SLAM)
            self._fuse_into_neighbours(kf)
            with self._locked():
                if not self._in_map(kf):
                    return
                self.map.update_covisibility(kf)
                window = self._local_window(kf)
            self._adjust(window, interruptible=True)
            with self._locked():
                if self._in_map(kf):
                    self._cull_keyframes(kf)
        with self._locked():  # every keyframe goes to loop detection, as in ORB-SLAM
            if not self._in_map(kf) or self.loop_closer is None:
                return
            graph = self.loop_closer.process(kf)
        if graph is None:
            return
        # the pose graph (seconds for hundreds of keyframes) is solved without the map lock, as
        # ORB-SLAM does: held, it stopped tracking for 4 s on a 5-minute flight
        optimised = self.adjuster.solve_graph(graph)
        with self._locked():
            self.loop_closer.apply(graph, optimised)
            window = whole_map_problem(self.map, self.extractor.scale_factors, self.K)
        self._adjust(window, interruptible=False)

    def _in_map(self, kf: KeyFrame) -> bool:
        """Still in the map: tracking discards a failed start's map while its keyframes may be
        queued or half mapped (checked under the lock, at every step)."""
        return kf.id in self.map.keyframes

    @contextmanager
    def _locked(self) -> Iterator[None]:
        """The map lock for one step of the work (a step for each neighbour where the work is per
        neighbour): held for a whole keyframe, it kept tracking waiting up to 0.2 s."""
        with self.map.lock:
            yield
        self.step_done()

    def _adjust(self, window: tuple[BundleProblem, list[int], list[int]] | None, interruptible: bool) -> None:
        """Bundle adjustment solved on a snapshot without the map lock (tracking goes on), the
        solution written back with it."""
        if window is None:
            return
        problem, kf_ids, point_ids = window
        solution = self.adjuster.solve(problem, self.settings.ba_evaluations, interruptible)
        with self.map.lock:
            apply_solution(self.map, problem, kf_ids, point_ids, solution, self.extractor.scale_factors)

    # --- steps ----------------------------------------------------------------------------

    def _register_observations(self, kf: KeyFrame, matched: np.ndarray) -> None:
        registered = []
        for index in np.flatnonzero(matched >= 0):
            point = self.map.points.get(int(matched[index]))
            if point is None or kf.id in point.observations:
                continue
            self.map.add_observation(point, kf, int(index))
            registered.append(point.id)
        self.map.refresh_points(registered, self.extractor.scale_factors)

    def _cull_recent_points(self, kf: KeyFrame) -> None:
        kept = []
        for point_id in self.recent_points:
            point = self.map.points.get(point_id)
            if point is None:
                continue
            age = kf.id - point.first_kf
            if point.found_ratio < 0.25 or (age >= 2 and len(point.observations) <= 2):
                self.map.remove_point(point_id)
            elif age < 3:
                kept.append(point_id)
        self.recent_points = kept

    def _triangulate_new_points(self, kf: KeyFrame) -> None:
        s = self.settings
        sigma2 = self.extractor.level_sigma2
        scale = self.extractor.settings.scale_factor
        fx = self.K[0, 0]
        starved = (kf.point_ids >= 0).sum() < STARVED_SHARE * len(kf.point_ids)
        min_parallax_cos = self._starved_min_parallax_cos if starved else self._min_parallax_cos
        for neighbour_id in kf.best_covisible(s.covisible_keyframes):
            with self._locked():
                nb = self.map.keyframes.get(neighbour_id)
                if nb is not None and self._in_map(kf):
                    self._triangulate_with(kf, nb, sigma2, scale, fx, min_parallax_cos)

    def _triangulate_with(self, kf: KeyFrame, nb: KeyFrame, sigma2: np.ndarray, scale: float, fx: float, min_parallax_cos: float) -> None:
        """New points from unmatched features of two keyframes (epipolar band, descriptor ratio,
        rotation consistency, parallax, reprojection and scale checks)."""
        baseline = np.linalg.norm(kf.centre - nb.centre)
        if baseline < 0.01 * self.map.median_depth(nb):  # a neighbour that sees no points yet (NaN) is not held to it
            return
        free_a = np.flatnonzero(kf.point_ids < 0)
        free_b = np.flatnonzero(nb.point_ids < 0)
        if len(free_a) == 0 or len(free_b) == 0:
            return
        fa, fb = kf.features, nb.features
        lens_b = None if fb.lens_jacobian is None else fb.lens_jacobian[free_b]
        # a chi-square gate, like the weighting: in detected pixels on every lens with distortion
        tolerance = np.sqrt(CHI2_1DOF * sigma2[fb.octave[free_b]]) / fx * window_stretch(lens_b)
        rows, cols = epipolar_pairs(kf.T_cw, nb.T_cw, fa.normalised[free_a], fb.normalised[free_b], tolerance)
        distances = hamming_pairs(fa.descriptors, fb.descriptors, free_a[rows], free_b[cols])
        rows, cols = best_unique_pairs(rows, cols, distances, TH_LOW, 0.6)
        if len(rows) == 0:
            return
        keep = rotation_consistent(fa.angle[free_a][rows], fb.angle[free_b][cols])
        ia, ib = free_a[rows[keep]], free_b[cols[keep]]
        points = triangulate(kf.T_cw, nb.T_cw, fa.normalised[ia], fb.normalised[ib])
        lens_a = None if fa.lens_jacobian is None else fa.lens_jacobian[ia]
        lens_b = None if fb.lens_jacobian is None else fb.lens_jacobian[ib]
        good, _ = check_points(
            points, kf.T_cw, nb.T_cw, fa.normalised[ia], fb.normalised[ib], fx, sigma2[fa.octave[ia]], sigma2[fb.octave[ib]], min_parallax_cos, lens_a, lens_b
        )
        # scale consistency: distance ratio agrees with the octave ratio
        da = np.linalg.norm(points - kf.centre, axis=1)
        db = np.linalg.norm(points - nb.centre, axis=1)
        with np.errstate(divide="ignore", invalid="ignore"):
            ratio_dist = da / db
            ratio_octave = self.extractor.scale_factors[fa.octave[ia]] / self.extractor.scale_factors[fb.octave[ib]]
        factor = 1.5 * scale
        good &= (ratio_dist * factor > ratio_octave) & (ratio_dist < ratio_octave * factor)
        created: list[int] = []
        for a, b, position in zip(ia[good], ib[good], points[good], strict=True):
            if kf.point_ids[a] >= 0 or nb.point_ids[b] >= 0:
                continue
            point = self.map.add_point(position, fa.descriptors[a], kf.id)
            self.map.add_observation(point, kf, int(a))
            self.map.add_observation(point, nb, int(b))
            created.append(point.id)
        self.map.refresh_points(created, self.extractor.scale_factors)
        self.recent_points += created

    def _fuse_into_neighbours(self, kf: KeyFrame) -> None:
        """Project the keyframe's points into its neighbours (ORB-SLAM's Fuse)."""
        ids = [int(i) for i in kf.point_ids[kf.point_ids >= 0]]
        changed: set[int] = set()
        for neighbour_id in kf.best_covisible(self.settings.covisible_keyframes):
            with self._locked():
                nb = self.map.keyframes.get(neighbour_id)
                if nb is not None and self._in_map(kf):
                    changed |= fuse_points(self.map, self.extractor, self.K, self.bounds, nb, ids)
        with self._locked():
            self.map.refresh_points(sorted(p for p in changed if p in self.map.points), self.extractor.scale_factors)

    def _local_window(self, kf: KeyFrame) -> tuple[BundleProblem, list[int], list[int]] | None:
        """The keyframe and its best covisible neighbours, free; other keyframes seeing their
        points, fixed (plus the first keyframe, and at least two poses in all)."""
        local_ids = [kf.id] + [k for k in kf.best_covisible(self.settings.local_ba_keyframes - 1) if k in self.map.keyframes]
        local = set(local_ids)
        point_ids = sorted({int(p) for k in local_ids for p in self.map.keyframes[k].point_ids if p >= 0 and int(p) in self.map.points})
        if len(point_ids) < 10:
            return None
        fixed_ids = sorted({o for p in point_ids for o in self.map.points[p].observations if o not in local and o in self.map.keyframes})
        kf_ids = local_ids + fixed_ids
        fixed = np.array([k not in local for k in kf_ids])
        origin = self.map.origin_id
        if origin in local:
            fixed[kf_ids.index(origin)] = True  # the first keyframe anchors the map
        # a monocular window needs two fixed poses: one leaves the scale free to drift
        for k in sorted(local_ids):
            if fixed.sum() >= 2 or k == kf.id:
                break
            fixed[kf_ids.index(k)] = True
        return window_problem(self.map, kf_ids, point_ids, fixed, self.extractor.scale_factors, self.K), kf_ids, point_ids

    def _cull_keyframes(self, kf: KeyFrame) -> None:
        """Drop neighbours whose points are nearly all seen by 3 other keyframes at the same or a
        finer scale: they add computation, not information."""
        origin = self.map.origin_id
        for neighbour_id in kf.best_covisible(self.settings.local_ba_keyframes):
            nb = self.map.keyframes.get(neighbour_id)
            if nb is None or nb.id == origin or nb.id == kf.id:
                continue
            rows = self.map.rows_with_points(nb.point_ids)
            if len(rows) == 0:
                continue
            point_row, kf_ids, indices = self.map.observation_table(nb.point_ids[rows].tolist())
            finer = self.map.gather_features(kf_ids, indices, "octave") <= nb.features.octave[rows][point_row] + 1
            seen = np.bincount(point_row[(kf_ids != nb.id) & finer], minlength=len(rows))
            if np.count_nonzero(seen >= 3) > self.settings.keyframe_redundancy * len(rows):
                self.map.remove_keyframe(nb.id)


class Mapping(Protocol):
    """How local mapping is scheduled beside tracking (what :class:`~evp.slam.system.SlamSystem`
    calls): in its thread (:class:`InlineMapping`) or in another (evp.runtime's mapping worker)."""

    mapper: LocalMapper
    mapping_ms: list[float]  # per keyframe mapped
    max_queue: int  # most keyframes ever waiting

    @property
    def idle(self) -> bool:
        """Whether tracking may insert keyframes freely (nothing queued or being mapped)."""
        ...

    @property
    def pending(self) -> int:
        """Keyframes waiting (not counting one being mapped)."""
        ...

    def submit(self, item: NewKeyFrame) -> None: ...

    def settle(self) -> None:
        """Map what inline mapping holds back (called before each frame is tracked)."""
        ...

    def interrupt(self) -> None:
        """Tracking needs a keyframe: cut the running bundle adjustment short (ORB-SLAM's InterruptBA)."""
        ...

    def finish(self) -> None:
        """Map every keyframe submitted, then stop; raises what mapping raised."""
        ...


class InlineMapping:
    """Local mapping in the tracking thread (the core's default: deterministic runs, tests and replays).

    A keyframe is mapped when the next frame arrives (``settle``), before that frame is tracked:
    the same order of work as mapping at once, but the pose of the keyframe's own frame is
    answered without waiting for its local bundle adjustment.
    """

    def __init__(self, mapper: LocalMapper):
        self.mapper = mapper
        self.mapping_ms: list[float] = []
        self.max_queue = 0
        self.idle = True
        self.pending = 0
        self._queue: list[NewKeyFrame] = []

    def interrupt(self) -> None:
        """Never busy while tracking runs: nothing to interrupt."""

    def submit(self, item: NewKeyFrame) -> None:
        self._queue.append(item)

    def settle(self) -> None:
        while self._queue:
            start = time.perf_counter()
            self.mapper.process(self._queue.pop(0))
            self.mapping_ms.append((time.perf_counter() - start) * 1000.0)

    def finish(self) -> None:
        self.settle()
