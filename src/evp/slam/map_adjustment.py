"""Bundle adjustment of part of the map: the problem built from keyframes and points, and the
solution written back (poses, positions, outlying observations dropped). Used by initialisation
(both keyframes), by local mapping (a covisible window) and by loop closing (the whole map)."""

from __future__ import annotations

import numpy as np

from evp.optim.bundle_adjustment import BundleProblem, bundle_adjust
from evp.optim.reprojection import CHI2_2DOF
from evp.slam.map import Map


def window_problem(slam_map: Map, kf_ids: list[int], point_ids: list[int], fixed: np.ndarray, scale_factors: np.ndarray, K: np.ndarray) -> BundleProblem:
    """Every observation of ``point_ids`` by ``kf_ids``; poses flagged in ``fixed`` stay put."""
    rows, observers, indices = slam_map.observation_table(point_ids)
    window = np.asarray(kf_ids, int)
    order = np.argsort(window)
    slot = np.minimum(np.searchsorted(window[order], observers), len(window) - 1)
    inside = window[order][slot] == observers
    rows, observers, indices = rows[inside], observers[inside], indices[inside]
    pose_array = order[slot[inside]]
    observed = slam_map.gather_features(observers, indices, "un_px").reshape(-1, 2)
    octave = slam_map.gather_features(observers, indices, "octave").astype(int)
    return BundleProblem(
        np.array([slam_map.keyframes[k].T_cw for k in kf_ids]),
        slam_map.store.position[np.asarray(point_ids, int)],
        pose_array,
        rows,
        observed,
        scale_factors[octave],
        fixed,
        K,
        slam_map.gather_lens_jacobians(observers, indices),
    )


def apply_solution(
    slam_map: Map,
    problem: BundleProblem,
    kf_ids: list[int],
    point_ids: list[int],
    solution: tuple[np.ndarray, np.ndarray, np.ndarray],
    scale_factors: np.ndarray,
) -> None:
    """Write poses and positions back (skipping what was removed meanwhile) and drop observations
    the solution leaves outside the chi-square bound."""
    poses, points, chi2 = solution
    for i, k in enumerate(kf_ids):
        if not problem.fixed[i] and k in slam_map.keyframes:
            slam_map.keyframes[k].set_pose(poses[i])
    alive = np.fromiter((p in slam_map.points for p in point_ids), bool, len(point_ids))
    slam_map.store.position[np.asarray(point_ids, int)[alive]] = points[alive]
    for n in np.flatnonzero(~(chi2 < CHI2_2DOF)):
        point = slam_map.points.get(point_ids[problem.point_index[n]])
        if point is not None:
            slam_map.remove_observation(point, kf_ids[problem.pose_index[n]])
    slam_map.refresh_points([p for p in point_ids if p in slam_map.points], scale_factors, descriptor=False)


def whole_map_problem(
    slam_map: Map, scale_factors: np.ndarray, K: np.ndarray, point_ids: list[int] | None = None
) -> tuple[BundleProblem, list[int], list[int]] | None:
    """Global bundle adjustment's problem: every keyframe and ``point_ids`` (default: every point),
    the first keyframe fixed."""
    kf_ids = sorted(slam_map.keyframes)
    point_ids = sorted(slam_map.points) if point_ids is None else point_ids
    if len(kf_ids) < 2 or not point_ids:
        return None
    fixed = np.arange(len(kf_ids)) == 0
    return window_problem(slam_map, kf_ids, point_ids, fixed, scale_factors, K), kf_ids, point_ids


def long_track_points(slam_map: Map, per_keyframe: int) -> list[int]:
    """Ids, ascending, of the points that are among the ``per_keyframe`` most observed of at least
    one keyframe that sees them (every point of a keyframe that has fewer).

    A point seen by few keyframes is triangulated from a short, low-parallax track; its noise-
    driven depth error does not average out, and shared by many such points it biases the poses:
    on the rendered circle (1000 features, a keyframe every 1.5 frames, half the points seen by
    <= 5 keyframes) the floor came out as a 0.9-degree cone and every camera tilted to match
    (bench/README.md, fourteenth session)."""
    kept: set[int] = set()
    for kf in slam_map.keyframes.values():
        ids = kf.point_ids[kf.point_ids >= 0].tolist()  # always live points: the Map keeps them in step
        ids.sort(key=lambda p: -len(slam_map.points[p].observations))
        kept.update(ids[:per_keyframe])
    return sorted(kept)


def adjust_whole_map(slam_map: Map, scale_factors: np.ndarray, K: np.ndarray, evaluations: int, points_per_keyframe: int = 0) -> None:
    """Global bundle adjustment, solved in place (the caller holds the map lock). With
    ``points_per_keyframe``, the poses are adjusted on each keyframe's longest tracks
    (:func:`long_track_points`), then the other points alone, on the adjusted poses."""
    if points_per_keyframe <= 0:
        _adjust(slam_map, whole_map_problem(slam_map, scale_factors, K), scale_factors, evaluations)
        return
    long_tracks = long_track_points(slam_map, points_per_keyframe)
    _adjust(slam_map, whole_map_problem(slam_map, scale_factors, K, long_tracks), scale_factors, evaluations)
    kept = set(long_tracks)
    others = [p for p in sorted(slam_map.points) if p not in kept]
    if others:
        kf_ids = sorted(slam_map.keyframes)
        every_pose_fixed = np.ones(len(kf_ids), bool)  # points only: the poses stay as the long tracks set them
        _adjust(slam_map, (window_problem(slam_map, kf_ids, others, every_pose_fixed, scale_factors, K), kf_ids, others), scale_factors, evaluations)


def _adjust(slam_map: Map, built: tuple[BundleProblem, list[int], list[int]] | None, scale_factors: np.ndarray, evaluations: int) -> None:
    if built is not None:
        problem, kf_ids, point_ids = built
        apply_solution(slam_map, problem, kf_ids, point_ids, bundle_adjust(problem, evaluations), scale_factors)
