"""The filter fed features whose identity is known, as in seed 001's experiment (features picked
by hand in each frame): no image, no matching, so that the filter's own convergence can be studied
(its Figures 9-12) and tested on exact data."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from evp.ekf_slam.filter import EkfSlamFilter

NO_DESCRIPTOR = np.zeros(32, dtype=np.uint8)


@dataclass(frozen=True)
class KnownFeatureRun:
    """Per wheel sample: ``poses`` (N, 3) estimated x, y, heading and ``position_sigma`` (N,) the
    1-sigma of the position (root of the covariance's trace over x, y); per frame: ``frame_times``
    and ``feature_points`` (F, P, 3), each known point's estimate (NaN before it is in the state);
    ``feature_of``: the filter's feature id of each point index."""

    poses: np.ndarray
    position_sigma: np.ndarray
    frame_times: np.ndarray
    feature_points: np.ndarray
    feature_of: dict[int, int]


def run_known_features(
    flt: EkfSlamFilter,
    times: np.ndarray,
    speeds: np.ndarray,
    yaw_rates: np.ndarray,
    frame_every: int,
    observe: Callable[[int], dict[int, np.ndarray]],
    point_count: int,
    max_features: int,
    on_new_feature: Callable[[EkfSlamFilter, int, int], None] = lambda flt, feature_id, point: None,
    given: dict[int, int] | None = None,
) -> KnownFeatureRun:
    """Wheel samples ``(times, speeds, yaw_rates)`` through ``flt``; every ``frame_every``-th
    sample is a frame, where ``observe(sample index)`` gives the normalised coordinates of the
    points in view by point index. Points in the state are fused; points in view not yet in it are
    added (up to ``max_features``), ``on_new_feature`` told of each (e.g. to start it wrong).
    ``given``: features already in the filter, point index -> feature id."""
    feature_of: dict[int, int] = dict(given or {})
    point_of: dict[int, int] = {f: p for p, f in feature_of.items()}
    poses = np.zeros((len(times), 3))
    sigma = np.zeros(len(times))
    frame_times, points = [], []
    for k, t in enumerate(times):
        flt.predict(t, speeds[k], yaw_rates[k])
        if k % frame_every == 0:
            seen = observe(k)
            features = [f for f in flt.features if point_of[f.id] in seen]
            if features:
                predictions = flt.predict_features(features)
                flt.update(t, predictions, np.arange(len(features)), np.array([seen[point_of[f.id]] for f in features]))
            for point, z in seen.items():
                if point not in feature_of and len(flt.features) < max_features:
                    feature = flt.add_feature(z, NO_DESCRIPTOR, t)
                    feature_of[point], point_of[feature.id] = feature.id, point
                    on_new_feature(flt, feature.id, point)
            flt.make_euclidean()
            estimate = np.full((point_count, 3), np.nan)
            for f, p in zip(flt.features, flt.feature_points()):
                estimate[point_of[f.id]] = p
            frame_times.append(t)
            points.append(estimate)
        poses[k] = flt.x[:3]
        sigma[k] = np.sqrt(flt.P[0, 0] + flt.P[1, 1])
    return KnownFeatureRun(poses, sigma, np.array(frame_times), np.array(points), feature_of)
