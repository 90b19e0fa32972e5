"""Loop closing (ORB-SLAM's LoopClosing): when the camera comes back to a mapped place, join the
two ends of the map and spread the drift between them.

For each keyframe local mapping has finished:

1. detection: keyframes whose bag-of-words vectors look alike (``keyframe_database.py``) and are
   not already covisible with it, scoring at least as well as its own covisible neighbours, and
   found again for three keyframes in a row (a place seen once by chance is not a loop);
2. verification: descriptor matches between the two keyframes' map points, a similarity
   (pose and scale: a monocular map drifts in both) by RANSAC, then the loop side's points are
   projected through it to find more matches; at least ``loop_min_matches`` are needed, and
   three keyframes in a row must each verify the loop and measure the same correction
   (ORB-SLAM3's verification in time);
3. correction: the keyframe and its covisible neighbours are moved by the similarity with their
   points, the duplicated points are merged, the pose graph (covisibility edges plus the new loop
   edges) is optimised over similarities and every point follows its reference keyframe; local
   mapping then refines the whole map by global bundle adjustment.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from evp.config import SlamSettings
from evp.geometry.sim3 import Sim3
from evp.geometry.transforms import rotation_angle, se3_inverse
from evp.slam.essential_graph import optimise_pose_graph
from evp.slam.map import KeyFrame, Map
from evp.slam.point_fusion import fuse_points
from evp.slam.pose_optimizer import optimise_pose, rotation_std_deg
from evp.slam.projection import project_points, undistorted_bounds
from evp.slam.sim3_estimation import estimate_sim3
from evp.vision.matching import TH_LOW, match_descriptors, match_in_window, rotation_consistent
from evp.vision.orb import OrbExtractor

MIN_KEYFRAMES = 20  # no loop in a map smaller than this (ORB-SLAM: 10 keyframes since the last loop)
NEIGHBOUR_MIN_WEIGHT = 30  # covisible neighbours setting the similarity bar (ORB-SLAM's)
CONSISTENT_DETECTIONS = 3  # keyframes in a row that must find the same place
GRAPH_MIN_WEIGHT = 100  # covisibility edges kept in the essential graph (ORB-SLAM's)
LOOP_MAX_ROTATION_STD_DEG = 0.5  # a loop's matches must fix the keyframe's rotation this well (1 sigma at 1 px)
VERIFICATIONS_IN_TIME = 3  # keyframes in a row that must verify a loop and agree on its correction


@dataclass(frozen=True)
class LoopClosure:
    keyframe: int
    loop_keyframe: int
    timestamp: float
    matches: int
    scale: float  # scale correction the loop revealed (1: no scale drift)


@dataclass
class _Candidate:
    keyframe: KeyFrame
    S_kw: Sim3  # corrected world-to-camera similarity of the current keyframe
    matches: dict[int, int]  # current keyframe's feature index -> loop map point
    correction: np.ndarray  # rotation of the map's world the loop implies, as this keyframe measured it
    rotation_std_deg: float  # how well its matches fix that (1 sigma, largest axis)


@dataclass
class GraphCorrection:
    """A loop's pose graph, built under the map lock and solved without it (tracking goes on);
    :meth:`LoopCloser.apply` writes the solution back."""

    closure: LoopClosure
    keyframe_ids: list[int]  # the graph's nodes, ascending
    initial: Sim3
    fixed: np.ndarray
    edge_i: np.ndarray
    edge_j: np.ndarray
    measured: Sim3

    def solve(self) -> Sim3:
        return optimise_pose_graph(self.initial, self.fixed, self.edge_i, self.edge_j, self.measured)


class LoopCloser:
    def __init__(self, slam_map: Map, extractor: OrbExtractor, settings: SlamSettings):
        self.map = slam_map
        self.extractor = extractor
        self.settings = settings
        self.K = extractor.camera.K
        self.bounds = undistorted_bounds(extractor)
        self.closures: list[LoopClosure] = []
        self._groups: list[tuple[set[int], int]] = []  # candidate groups and their detection streaks
        self._verified: list[_Candidate] = []  # loops verified by the last keyframes in a row
        self._last_loop_kf = -(10**9)

    def process(self, kf: KeyFrame) -> GraphCorrection | None:
        """Look for a loop at ``kf``; when one is found, move the keyframe's side onto the loop
        and merge the two, and return the pose graph that spreads the correction over the map
        (the caller holds the map lock; it solves the graph without it, calls :meth:`apply`, then
        runs a global bundle adjustment)."""
        for candidate in self._detect(kf):
            found = self._verify(kf, candidate)
            if found is not None:
                self._verified = [*self._verified, found][-VERIFICATIONS_IN_TIME:]
                agreed = len(self._verified) == VERIFICATIONS_IN_TIME and _corrections_agree(self._verified)
                return self._correct(kf, found) if agreed else None
        self._verified = []
        return None

    # --- detection --------------------------------------------------------------------------

    def _detect(self, kf: KeyFrame) -> list[KeyFrame]:
        keyframes = self.map.keyframes
        if len(keyframes) < MIN_KEYFRAMES or kf.id - self._last_loop_kf < MIN_KEYFRAMES:
            self._groups = []
            return []
        database = self.map.database
        neighbours = [k for k in kf.best_covisible(len(kf.covisible), NEIGHBOUR_MIN_WEIGHT) if k in keyframes]
        candidates = database.loop_candidates(kf.id, keyframes, set(kf.covisible), neighbours)
        groups, accepted = [], []
        for k in candidates:
            group = {k} | set(keyframes[k].covisible)
            streak = max((count for previous, count in self._groups if previous & group), default=0) + 1
            groups.append((group, streak))
            if streak >= CONSISTENT_DETECTIONS:
                accepted.append(keyframes[k])
        self._groups = groups
        return accepted[:3]

    # --- verification -----------------------------------------------------------------------

    def _verify(self, kf: KeyFrame, loop_kf: KeyFrame) -> _Candidate | None:
        rows_a = self.map.rows_with_points(kf.point_ids)
        rows_b = self.map.rows_with_points(loop_kf.point_ids)
        fa, fb = kf.features, loop_kf.features
        a, b = match_descriptors(fa.descriptors[rows_a], fb.descriptors[rows_b], TH_LOW, 0.75)
        keep = rotation_consistent(fa.angle[rows_a[a]], fb.angle[rows_b[b]])
        ia, ib = rows_a[a[keep]], rows_b[b[keep]]
        positions = self.map.store.position
        Xa = positions[kf.point_ids[ia]] @ kf.T_cw[:3, :3].T + kf.T_cw[:3, 3]
        Xb = positions[loop_kf.point_ids[ib]] @ loop_kf.T_cw[:3, :3].T + loop_kf.T_cw[:3, 3]
        w = self.extractor.inv_level_sigma2
        lens_a = None if fa.lens_jacobian is None else fa.lens_jacobian[ia]
        lens_b = None if fb.lens_jacobian is None else fb.lens_jacobian[ib]
        estimate = estimate_sim3(Xa, Xb, fa.un_px[ia], fb.un_px[ib], w[fa.octave[ia]], w[fb.octave[ib]], self.K, seed=kf.id, lens_a=lens_a, lens_b=lens_b)
        if estimate is None:
            return None
        S_ab, inliers = estimate
        S_kw = S_ab @ Sim3.from_se3(loop_kf.T_cw)
        matches = {int(i): int(loop_kf.point_ids[j]) for i, j in zip(ia[inliers], ib[inliers], strict=True)}
        self._search_loop_points(kf, S_kw, self._loop_points(loop_kf), matches)
        S_kw, matches, rotation_std = self._agreeing_matches(kf, S_kw, matches)
        if len(matches) < self.settings.loop_min_matches:
            return None
        correction = kf.T_cw[:3, :3].T @ S_kw.R[0]
        return _Candidate(loop_kf, S_kw, matches, correction, rotation_std)

    def _agreeing_matches(self, kf: KeyFrame, S_kw: Sim3, matches: dict[int, int]) -> tuple[Sim3, dict[int, int], float]:
        """The keyframe's pose in the loop's world refined on every match (pose-only, Huber kernel,
        chi-square rounds; the similarity's scale kept), and the matches that agree with it; none
        when they fix the rotation worse than :data:`LOOP_MAX_ROTATION_STD_DEG`.

        On repetitive ground a wrong similarity finds look-alikes near its wrong projections; they
        do not agree on one pose and drop out here. A place seen again over a part of the image
        (bag-of-words candidates come before the views coincide) may give true matches that barely
        fix the pose: on a tiled floor, 79 matches in a strip of the image slid the keyframe 27
        degrees away to absorb 1 cm of drift. Such a loop would add error, not remove it; a later
        keyframe with more overlap closes it. Also returns that rotation uncertainty."""
        rows = np.fromiter(matches, int, len(matches))
        ids = np.array([matches[r] for r in rows.tolist()], int)
        if len(rows) < 6:
            return S_kw, {}, np.inf
        features = kf.features
        positions, inv_sigma2 = self.map.store.position[ids], self.extractor.inv_level_sigma2[features.octave[rows]]
        lens = None if features.lens_jacobian is None else features.lens_jacobian[rows]
        T, agree = optimise_pose(S_kw.to_se3()[0], positions, features.un_px[rows], inv_sigma2, self.K, lens)
        agreeing_lens = None if lens is None else lens[agree]
        rotation_std = float(rotation_std_deg(T, positions[agree], inv_sigma2[agree], self.K, agreeing_lens).max()) if agree.sum() >= 6 else np.inf
        if rotation_std > LOOP_MAX_ROTATION_STD_DEG:
            return S_kw, {}, rotation_std
        scale = float(S_kw.s[0])
        return Sim3.one(scale, T[:3, :3], T[:3, 3] * scale), dict(zip(rows[agree].tolist(), ids[agree].tolist())), rotation_std

    def _loop_points(self, loop_kf: KeyFrame) -> np.ndarray:
        """Ids, ascending, of the points of the loop keyframe and its best covisible neighbours."""
        keyframes = self.map.keyframes
        seen = np.concatenate([keyframes[k].point_ids for k in [loop_kf.id, *loop_kf.best_covisible(10)] if k in keyframes])
        ids = np.unique(seen[seen >= 0])
        return ids[self.map.store.alive[ids]]

    def _search_loop_points(self, kf: KeyFrame, S_kw: Sim3, point_ids: np.ndarray, matches: dict[int, int]) -> None:
        """Add to ``matches`` the loop points found by projection through ``S_kw``."""
        ids = point_ids[~np.isin(point_ids, np.fromiter(matches.values(), int, len(matches)))]
        projection = project_points(self.map, ids, S_kw.to_se3()[0], self.extractor, self.K, self.bounds)
        if projection is None:
            return
        free = np.setdiff1d(np.arange(len(kf.features)), np.fromiter(matches, int, len(matches)))
        features = kf.features
        radius = 10.0 * self.extractor.scale_factors[projection.level] * projection.stretch
        a, b = match_in_window(
            self.map.store.descriptor[ids[projection.rows]],
            projection.uv,
            features.descriptors[free],
            features.un_px[free],
            radius,
            TH_LOW,  # ORB-SLAM's bar here: TH_HIGH let a wrong similarity collect look-alikes
            1.0,
            projection.level,
            features.octave[free],
        )
        for r, index in zip(a, b, strict=True):
            matches[int(free[index])] = int(ids[projection.rows[r]])

    # --- correction -------------------------------------------------------------------------

    def _correct(self, kf: KeyFrame, loop: _Candidate) -> GraphCorrection:
        keyframes = self.map.keyframes
        group = [kf.id] + [k for k in kf.covisible if k in keyframes]
        before = {k: keyframes[k].T_cw.copy() for k in keyframes}
        neighbours_before = {k: set(keyframes[k].covisible) for k in group}
        T_wk = se3_inverse(kf.T_cw)
        corrected = {k: Sim3.from_se3(before[k] @ T_wk) @ loop.S_kw for k in group}
        self._move_points(group, Sim3.from_se3(np.array([before[k] for k in group])), Sim3.stack([corrected[k] for k in group]))
        for k in group:
            keyframes[k].set_pose(corrected[k].to_se3()[0])
        self._merge(kf, loop)
        for k in group:
            self.map.update_covisibility(keyframes[k])
        loop_edges = {
            (k, j) for k in group if k in keyframes for j in keyframes[k].covisible if j not in neighbours_before[k] and j not in group and j in keyframes
        }
        loop_edges.add((kf.id, loop.keyframe.id))
        self._last_loop_kf = kf.id
        self._groups = []
        self._verified = []
        closure = LoopClosure(kf.id, loop.keyframe.id, kf.timestamp, len(loop.matches), float(loop.S_kw.s[0]))
        self.closures.append(closure)
        return self._graph(closure, before, corrected, loop_edges, loop.keyframe.id)

    def _move_points(self, kf_ids: list[int], old: Sim3, new: Sim3) -> None:
        """Points seen by ``kf_ids`` keep their place in their reference keyframe (their first
        keyframe, or else the first of ``kf_ids`` observing them) as it moves from ``old`` to
        ``new`` (stacks in the order of ``kf_ids``)."""
        slot = {k: n for n, k in enumerate(kf_ids)}
        point_ids, references = [], []
        for point_id, point in self.map.points.items():
            reference = point.first_kf if point.first_kf in slot else next((k for k in point.observations if k in slot), None)
            if reference is not None:
                point_ids.append(point_id)
                references.append(slot[reference])
        if not point_ids:
            return
        rows, refs = np.array(point_ids), np.array(references)
        store = self.map.store
        store.position[rows] = new[refs].inverse().apply(old[refs].apply(store.position[rows]))

    def _merge(self, kf: KeyFrame, loop: _Candidate) -> None:
        """The loop's points replace the current side's duplicates, in the keyframe itself (its
        verified matches) and in its neighbours (by projection)."""
        for index, point_id in loop.matches.items():
            point = self.map.points.get(point_id)
            if point is None or kf.id in point.observations:
                continue
            existing = int(kf.point_ids[index])
            if existing >= 0 and existing in self.map.points:
                self.map.replace_point(existing, point_id)
            else:
                self.map.add_observation(point, kf, index)
        loop_points = self._loop_points(loop.keyframe).tolist()
        changed = set(loop_points)
        for k in [kf.id, *kf.covisible]:
            if k in self.map.keyframes:
                changed |= fuse_points(self.map, self.extractor, self.K, self.bounds, self.map.keyframes[k], loop_points, radius_px=4.0)
        self.map.refresh_points(sorted(p for p in changed if p in self.map.points), self.extractor.scale_factors)

    def _graph(
        self, closure: LoopClosure, before: dict[int, np.ndarray], corrected: dict[int, Sim3], loop_edges: set[tuple[int, int]], fixed_kf: int
    ) -> GraphCorrection:
        """The essential graph over all keyframes: covisibility edges keep the relative poses
        mapping had found, loop edges the corrected ones; the loop keyframe stays fixed."""
        keyframes = self.map.keyframes
        ids = sorted(keyframes)
        slot = {k: n for n, k in enumerate(ids)}
        start = {k: corrected.get(k, Sim3.from_se3(before[k])) for k in ids}
        pairs = set()
        for k in ids:
            kf = keyframes[k]
            older = [j for j in kf.best_covisible(len(kf.covisible)) if j < k and j in keyframes]
            pairs.update((k, j) for j in older if kf.covisible[j] >= GRAPH_MIN_WEIGHT)
            if older:
                pairs.add((k, older[0]))  # the strongest older neighbour keeps the graph connected
        pairs -= {(i, j) for i, j in loop_edges} | {(j, i) for i, j in loop_edges}
        edge_i = np.array([slot[i] for i, _ in pairs] + [slot[i] for i, _ in loop_edges], int)
        edge_j = np.array([slot[j] for _, j in pairs] + [slot[j] for _, j in loop_edges], int)
        initial = Sim3.stack([start[k] for k in ids])
        unmoved = Sim3.stack([Sim3.from_se3(before[k]) for k in ids])
        n_normal = len(pairs)
        measured = Sim3.stack(
            [
                unmoved[edge_i[:n_normal]] @ unmoved[edge_j[:n_normal]].inverse(),
                initial[edge_i[n_normal:]] @ initial[edge_j[n_normal:]].inverse(),
            ]
        )
        fixed = np.array([k == fixed_kf for k in ids])
        return GraphCorrection(closure, ids, initial, fixed, edge_i, edge_j, measured)

    def apply(self, graph: GraphCorrection, optimised: Sim3) -> None:
        """Write the solved graph back (the caller holds the map lock): keyframes take their
        optimised poses and every point follows its reference keyframe. Keyframes tracking added
        while the graph was solved follow the loop's keyframe, near which they were taken."""
        keyframes = self.map.keyframes
        if graph.closure.keyframe not in keyframes:  # tracking discarded the map meanwhile
            return
        ids = [k for k in graph.keyframe_ids if k in keyframes]
        rows = np.searchsorted(graph.keyframe_ids, ids)
        initial, optimised = graph.initial[rows], optimised[rows]
        self._move_points(ids, initial, optimised)
        poses = optimised.to_se3()
        for n, k in enumerate(ids):
            keyframes[k].set_pose(poses[n])
        anchor = ids.index(graph.closure.keyframe)
        follow = initial[anchor].inverse() @ optimised[anchor]  # world as optimised -> as the anchor was
        for k in set(keyframes) - set(graph.keyframe_ids):
            keyframes[k].set_pose((Sim3.from_se3(keyframes[k].T_cw[None]) @ follow).to_se3()[0])


def _corrections_agree(verified: list[_Candidate]) -> bool:
    """Each pair of keyframes measured the same rotation of the map's world, within three times
    their combined uncertainty. A true loop's correction is the drift, the same for neighbouring
    keyframes; one measured through points the map holds badly slid from 17 to 13 degrees over
    four keyframes (the drift was 2)."""
    for i, a in enumerate(verified):
        for b in verified[i + 1 :]:
            angle = np.degrees(rotation_angle(a.correction.T @ b.correction))
            if angle > 3.0 * np.hypot(a.rotation_std_deg, b.rotation_std_deg):
                return False
    return True
