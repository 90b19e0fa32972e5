"""Merging map points that are one (ORB-SLAM's Fuse), shared by local mapping and loop closing."""

from __future__ import annotations

import numpy as np

from evp.slam.map import KeyFrame, Map
from evp.slam.projection import project_points
from evp.vision.matching import TH_LOW, match_in_window
from evp.vision.orb import OrbExtractor


def fuse_points(
    slam_map: Map, extractor: OrbExtractor, K: np.ndarray, bounds: tuple[float, float, float, float], kf: KeyFrame, point_ids: list[int], radius_px: float = 3.0
) -> set[int]:
    """Project ``point_ids`` into ``kf``: a match either adds an observation or, where the
    keypoint already has a point, merges the two (the one with more observations is kept).

    Returns the points whose observations changed; the caller refreshes them
    (:meth:`Map.refresh_points`) once it has fused into every keyframe, as ORB-SLAM updates the
    points after all its Fuse calls (a refresh per call was a third of the fusing time)."""
    candidates = [i for i in point_ids if i in slam_map.points and kf.id not in slam_map.points[i].observations]
    if not candidates:
        return set()
    projected = project_points(slam_map, candidates, kf.T_cw, extractor, K, bounds)
    if projected is None:
        return set()
    radius = radius_px * extractor.scale_factors[projected.level] * projected.stretch
    descriptors = slam_map.store.descriptor[np.asarray(candidates)[projected.rows]]
    a, b = match_in_window(descriptors, projected.uv, kf.features.descriptors, kf.features.un_px, radius, TH_LOW, 1.0, projected.level, kf.features.octave)
    changed: set[int] = set()
    for r, index in zip(a, b, strict=True):
        point = slam_map.points.get(candidates[projected.rows[r]])
        if point is None or kf.id in point.observations:
            continue
        existing = int(kf.point_ids[index])
        if existing >= 0 and existing in slam_map.points:
            keep, drop = (existing, point.id) if len(slam_map.points[existing].observations) >= len(point.observations) else (point.id, existing)
            slam_map.replace_point(drop, keep)
            changed.add(keep)
        else:
            slam_map.add_observation(point, kf, int(index))
            changed.add(point.id)
    return changed
