"""Seed 001's EKF-SLAM core on exact synthetic data: a forward camera on a planar robot, world
points at known places, exact bearings (features of known identity), wheels with known errors."""

from __future__ import annotations

import math

import numpy as np

from evp.config import EkfSlamSettings
from evp.ekf_slam.filter import EkfSlamFilter, principal_submatrix
from evp.ekf_slam.inverse_depth import euclidean, ray_angles, ray_direction
from evp.ekf_slam.known_features import NO_DESCRIPTOR, run_known_features
from evp.fusion.planar_motion import dead_reckoning
from evp.sim.landmark_drive import CAMERA_OFFSET, FORWARD_CAMERA, drive, ring_loop


def new_filter(**settings) -> EkfSlamFilter:
    return EkfSlamFilter(FORWARD_CAMERA, CAMERA_OFFSET, EkfSlamSettings(**settings), 500.0)


def test_inverse_depth_round_trip():
    anchor, point = np.array([0.1, -0.2, 0.2]), np.array([2.0, 1.0, 0.7])
    azimuth, elevation, _ = ray_angles(point - anchor)
    feature = np.array([*anchor, azimuth, elevation, 1.0 / np.linalg.norm(point - anchor)])
    np.testing.assert_allclose(euclidean(feature)[0], point, atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(ray_direction(azimuth, elevation)), 1.0)


def test_features_at_known_depths_converge():
    """A straight drive towards points 2.5-4.5 m ahead, then a turn: exact bearings and wheels;
    every feature's point ends within 1 % of its distance."""
    rng = np.random.default_rng(1)
    points = np.column_stack([rng.uniform(2.5, 4.5, 12), rng.uniform(-1.5, 1.5, 12), rng.uniform(0.0, 1.0, 12)])
    n = 250
    scene = drive(np.full(n, 0.3), np.where(np.arange(n) > 150, 0.2, 0.0), points)
    flt = new_filter()
    run = run_known_features(flt, scene.times, scene.speeds, scene.yaw_rates, 5, scene.bearings, len(points), 100)
    assert len(run.feature_of) == 12
    final = run.feature_points[-1]
    distance = np.linalg.norm(points - [*CAMERA_OFFSET[:2], CAMERA_OFFSET[2]], axis=1)
    assert np.all(np.linalg.norm(final - points, axis=1) < 0.01 * distance)
    assert sum(not f.inverse_depth for f in flt.features) >= 6  # well-determined ones became Euclidean
    assert np.abs(run.poses[:, :2] - scene.poses[:, :2]).max() < 0.005
    assert not flt.warnings
    assert np.array_equal(flt.P, flt.P.T)  # exactly symmetric by construction: no pass over P undoes rounding


def test_a_known_loop_closes():
    """Twice round a 1 m circle inside a ring of points, the gyro biased by 0.01 rad/s (dead
    reckoning ends 0.4 m off): the second lap re-observes the first lap's features instead of
    adding new ones, the end is within 2 cm and the filter has learnt the bias."""
    scene = ring_loop()
    biased = dead_reckoning((0.0, 0.0, 0.0), scene.times, scene.speeds, scene.yaw_rates + 0.01)
    flt = new_filter()
    run = run_known_features(flt, scene.times, scene.speeds, scene.yaw_rates + 0.01, 5, scene.bearings, len(scene.points), 24)
    assert np.linalg.norm(biased[-1, :2] - scene.poses[-1, :2]) > 0.3
    assert np.linalg.norm(run.poses[-1, :2] - scene.poses[-1, :2]) < 0.02
    assert abs(math.remainder(run.poses[-1, 2] - scene.poses[-1, 2], 2 * math.pi)) < 0.01
    assert abs(flt.x[3] - 0.01) < 0.002
    assert len(run.feature_of) == 24
    assert np.array_equal(flt.P, flt.P.T)


def test_bad_wheel_and_gyro_samples_are_named_and_bridged():
    flt = new_filter()
    flt.predict(0.0, 0.0, 0.0)
    flt.predict(0.02, 0.3, 0.0)
    flt.predict(0.04, 655.35, 0.0)  # a 16-bit counter wrapped
    flt.predict(0.06, 0.3, 100.0)  # saturated gyro
    flt.predict(0.05, 0.3, 0.0)  # time going backwards
    assert len(flt.warnings) == 3 and "encoder jump" in flt.warnings[0] and "saturated" in flt.warnings[1] and "before" in flt.warnings[2]
    np.testing.assert_allclose(flt.x[:3], [0.018, 0.0, 0.0], atol=1e-9)  # each bad interval bridged with the last good input
    assert flt.P[0, 0] > 100 * new_filter().P[0, 0] + 1e-6


def test_inconsistent_innovations_raise_a_warning():
    """A feature whose bearing keeps jumping by 30 pixels: the update's NIS says so."""
    flt = new_filter(consistency_window_frames=5)
    flt.predict(0.0, 0.0, 0.0)
    feature = flt.add_feature(np.array([0.1, 0.0]), NO_DESCRIPTOR, 0.0)
    for k in range(1, 12):
        flt.predict(k * 0.1, 0.3, 0.0)
        predictions = flt.predict_features([feature])
        flt.update(k * 0.1, predictions, np.array([0]), predictions.z + [0.06 * (-1) ** k, 0.0])
    assert any("innovations inconsistent" in w for w in flt.warnings)


def test_principal_submatrix_is_fancy_indexing():
    P = np.arange(100.0).reshape(10, 10)
    for keep in (np.arange(10), np.array([0, 1, 2, 6, 7, 9]), np.array([3]), np.array([4, 5, 8])):
        np.testing.assert_array_equal(principal_submatrix(P, keep), P[np.ix_(keep, keep)])
