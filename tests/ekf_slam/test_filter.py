"""Seed 001's EKF-SLAM core on exact synthetic data: a forward camera on a planar robot, world
points at known places, exact bearings, wheels with known errors."""

from __future__ import annotations

import math

import numpy as np

from evp.config import EkfSlamSettings
from evp.ekf_slam.filter import EkfSlamFilter, yaw_rotation
from evp.ekf_slam.inverse_depth import euclidean, ray_angles, ray_direction
from evp.fusion.planar_motion import dead_reckoning

R_BODY_CAM = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])  # camera looking forward, image x right
T_BODY_CAM = np.array([0.05, 0.0, 0.2])
DESCRIPTOR = np.zeros(32, dtype=np.uint8)
RATE_HZ = 50.0


def camera_frame(pose: np.ndarray, points: np.ndarray) -> np.ndarray:
    """World points in the camera of the robot at ``pose`` (x, y, yaw)."""
    Rz = yaw_rotation(pose[2])
    centre = np.array([pose[0], pose[1], 0.0]) + Rz @ T_BODY_CAM
    return (points - centre) @ (Rz @ R_BODY_CAM)


def bearings(pose: np.ndarray, points: np.ndarray, half_fov: float = 0.6) -> tuple[np.ndarray, np.ndarray]:
    """Exact normalised coordinates of the points in view, and which are in view."""
    c = camera_frame(pose, points)
    seen = (c[:, 2] > 0.2) & (np.abs(c[:, 0] / np.maximum(c[:, 2], 1e-9)) < half_fov) & (np.abs(c[:, 1] / np.maximum(c[:, 2], 1e-9)) < half_fov)
    return c[:, :2] / np.where(seen, c[:, 2], 1.0)[:, None], seen


def run(truth: np.ndarray, speeds: np.ndarray, rates: np.ndarray, points: np.ndarray, gyro_bias: float, settings: EkfSlamSettings, max_features: int):
    """The filter over a driven track: wheel samples at 50 Hz, a frame every 5th; features are
    added for points in view that are not in the state (up to ``max_features``); returns the
    filter, the estimated poses and the feature -> point index map."""
    flt = EkfSlamFilter(R_BODY_CAM, T_BODY_CAM, settings, 500.0)
    times = np.arange(len(truth)) / RATE_HZ
    point_of: dict[int, int] = {}
    estimates = np.zeros_like(truth)
    for k, t in enumerate(times):
        flt.predict(t, speeds[k], rates[k] + gyro_bias)
        if k % 5 == 0:
            z, seen = bearings(truth[k], points)
            features = [f for f in flt.features if seen[point_of[f.id]]]
            if features:
                predictions = flt.predict_features(features)
                flt.update(t, predictions, np.arange(len(features)), z[[point_of[f.id] for f in features]])
            tracked = set(point_of.values())
            for i in np.flatnonzero(seen):
                if i not in tracked and len(flt.features) < max_features:
                    point_of[flt.add_feature(z[i], DESCRIPTOR, t).id] = int(i)
            flt.make_euclidean()
        estimates[k] = flt.x[:3]
    return flt, estimates, point_of


def drive(speeds: np.ndarray, rates: np.ndarray) -> np.ndarray:
    return dead_reckoning((0.0, 0.0, 0.0), np.arange(len(speeds)) / RATE_HZ, speeds, rates)


def test_inverse_depth_round_trip():
    anchor, point = np.array([0.1, -0.2, 0.2]), np.array([2.0, 1.0, 0.7])
    azimuth, elevation, _ = ray_angles(point - anchor)
    feature = np.array([*anchor, azimuth, elevation, 1.0 / np.linalg.norm(point - anchor)])
    np.testing.assert_allclose(euclidean(feature)[0], point, atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(ray_direction(azimuth, elevation)), 1.0)


def test_features_at_known_depths_converge():
    """A straight drive past a wall of points 2-4 m ahead and to the side, then a turn: exact
    bearings and wheels; every feature's point ends within 1 % of its depth."""
    rng = np.random.default_rng(1)
    points = np.column_stack([rng.uniform(2.5, 4.5, 12), rng.uniform(-1.5, 1.5, 12), rng.uniform(0.0, 1.0, 12)])
    n = 250
    speeds = np.full(n, 0.3)
    rates = np.where(np.arange(n) > 150, 0.2, 0.0)
    truth = drive(speeds, rates)
    flt, estimates, point_of = run(truth, speeds, rates, points, 0.0, EkfSlamSettings(), 100)
    assert len(point_of) == 12
    estimated = flt.feature_points()
    for f, p in zip(flt.features, estimated):
        true = points[point_of[f.id]]
        assert np.linalg.norm(p - true) < 0.01 * np.linalg.norm(true - [truth[0, 0], truth[0, 1], 0.2]), (f.id, p, true)
    assert sum(not f.inverse_depth for f in flt.features) >= 6  # well-determined ones became Euclidean
    assert np.abs(estimates[:, :2] - truth[:, :2]).max() < 0.005
    assert not flt.warnings


def test_a_known_loop_closes():
    """Twice round a 1 m circle inside a ring of points, the gyro biased by 0.01 rad/s (35 degrees
    over the drive, dead reckoning ends metres off): re-observing the first features closes the
    loop, and the filter learns the bias."""
    angles = np.linspace(0, 2 * np.pi, 24, endpoint=False)
    points = np.column_stack([3.0 * np.cos(angles), 3.0 * np.sin(angles) + 1.0, np.tile([0.1, 0.6, 1.1], 8)])
    n = int(2 * 2 * np.pi / 0.3 * RATE_HZ)  # 0.3 m/s round a 1 m radius, 0.3 rad/s: two turns
    speeds, rates = np.full(n, 0.3), np.full(n, 0.3)
    truth = drive(speeds, rates)
    biased = drive(speeds, rates + 0.01)
    flt, estimates, point_of = run(truth, speeds, rates, points, 0.01, EkfSlamSettings(), 24)
    end_error = np.linalg.norm(estimates[-1, :2] - truth[-1, :2])
    assert np.linalg.norm(biased[-1, :2] - truth[-1, :2]) > 0.3
    assert end_error < 0.02
    assert abs(math.remainder(estimates[-1, 2] - truth[-1, 2], 2 * math.pi)) < 0.01
    assert abs(flt.x[3] - 0.01) < 0.002
    assert len(point_of) == 24  # the second turn re-observed the first turn's features instead of adding new ones


def test_bad_wheel_and_gyro_samples_are_named_and_bridged():
    flt = EkfSlamFilter(R_BODY_CAM, T_BODY_CAM, EkfSlamSettings(), 500.0)
    flt.predict(0.0, 0.0, 0.0)
    flt.predict(0.02, 0.3, 0.0)
    flt.predict(0.04, 655.35, 0.0)  # a 16-bit counter wrapped
    flt.predict(0.06, 0.3, 100.0)  # saturated gyro
    flt.predict(0.05, 0.3, 0.0)  # time going backwards
    assert len(flt.warnings) == 3 and "encoder jump" in flt.warnings[0] and "saturated" in flt.warnings[1] and "before" in flt.warnings[2]
    np.testing.assert_allclose(flt.x[:3], [0.018, 0.0, 0.0], atol=1e-9)  # each bad interval bridged with the last good input
    assert flt.P[0, 0] > 100 * EkfSlamFilter(R_BODY_CAM, T_BODY_CAM, EkfSlamSettings(), 500.0).P[0, 0] + 1e-6


def test_inconsistent_innovations_raise_a_warning():
    """A feature whose bearing keeps jumping by 30 pixels: the update's NIS says so."""
    flt = EkfSlamFilter(R_BODY_CAM, T_BODY_CAM, EkfSlamSettings(consistency_window_frames=5), 500.0)
    flt.predict(0.0, 0.0, 0.0)
    feature = flt.add_feature(np.array([0.1, 0.0]), DESCRIPTOR, 0.0)
    for k in range(1, 12):
        flt.predict(k * 0.1, 0.3, 0.0)
        predictions = flt.predict_features([feature])
        flt.update(k * 0.1, predictions, np.array([0]), predictions.z + [0.06 * (-1) ** k, 0.0])
    assert any("innovations inconsistent" in w for w in flt.warnings)
