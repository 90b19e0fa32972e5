"""The visual map fitted to the trusted phase's GPS fixes: a known similarity recovered with an
honest uncertainty, the camera-to-body lever accounted for, a pull-off and a bad fix dropped, and
a specific reason where there is no fit."""

import numpy as np
from scipy.spatial.transform import Rotation

from evp.fusion.gps_map_fit import GpsMapPairs

SCALE = 3.7  # metres per map unit
R_WORLD_MAP = Rotation.from_euler("zyx", [40.0, 1.0, -0.5], degrees=True).as_matrix()
T_WORLD_MAP = np.array([12.0, -5.0, 30.0])
T_BODY_CAM = np.eye(4)
T_BODY_CAM[:3, :3] = Rotation.from_euler("x", 180.0, degrees=True).as_matrix()  # looking down
T_BODY_CAM[:3, 3] = [0.3, 0.0, -0.1]  # a lever that turns with the vehicle


def _flight(duration_s=60.0, frame_rate=30.0, gps_rate=10.0):
    """Camera poses in the map and the body's true world position, for a drone turning along a
    30 m circle at 30 m up (poses at the frame rate, fixes in between)."""
    def body(t):
        angle = t / 10.0
        position = np.array([30.0 * np.cos(angle), 30.0 * np.sin(angle), 30.0 + 0.1 * t])
        R = Rotation.from_euler("z", angle + np.pi / 2).as_matrix()
        return position, R

    def camera_in_map(t):
        position, R = body(t)
        R_world_cam = R @ T_BODY_CAM[:3, :3]
        world_cam = position + R @ T_BODY_CAM[:3, 3]
        T = np.eye(4)
        T[:3, :3] = R_WORLD_MAP.T @ R_world_cam
        T[:3, 3] = R_WORLD_MAP.T @ (world_cam - T_WORLD_MAP) / SCALE
        return T

    frames = np.arange(0.0, duration_s, 1.0 / frame_rate)
    fixes = np.arange(0.01, duration_s, 1.0 / gps_rate)
    return frames, camera_in_map, fixes, lambda t: body(t)[0]


def _pairs(noise_m=0.0, extra=lambda t: np.zeros(3), seed=0, max_span_s=600.0, **flight):
    frames, camera_in_map, fixes, body = _flight(**flight)
    rng = np.random.default_rng(seed)
    pairs = GpsMapPairs(T_BODY_CAM, max_span_s=max_span_s)
    events = sorted([(t, "pose") for t in frames] + [(t, "fix") for t in fixes])
    for t, kind in events:
        if kind == "pose":
            pairs.add_pose(t, camera_in_map(t))
        else:
            pairs.add_fix(t, body(t) + extra(t) + rng.normal(0.0, noise_m, 3))
    return pairs


def test_exact_fixes_give_the_map_s_similarity_with_the_lever_turned_into_it():
    fit = _pairs().fit(np.inf, 20.0, 60.0)
    assert abs(fit.scale / SCALE - 1) < 1e-4
    assert np.degrees(Rotation.from_matrix(fit.R_world_map @ R_WORLD_MAP.T).magnitude()) < 0.01
    assert np.linalg.norm(fit.t_world_map - T_WORLD_MAP) < 0.01
    assert fit.residual_m < 0.01 and fit.dropped == 0


def test_noisy_fixes_give_a_fit_within_its_stated_uncertainty():
    misses = []
    for seed in range(20):
        fit = _pairs(noise_m=1.5, seed=seed).fit(np.inf, 20.0, 60.0)
        misses.append(np.log(fit.scale / SCALE) / np.sqrt(fit.covariance[0, 0]))
    misses = np.array(misses)
    # white noise here: the 60 s correlation time makes the stated sigma a few times too wide,
    # never too narrow
    assert np.abs(misses).max() < 3.0
    assert 0.3 < np.sqrt(fit.covariance[0, 0]) * 100 < 5.0  # per cent: 1.5 m fixes over a 30 m circle


def test_a_pull_off_and_a_bad_fix_are_dropped():
    pull = lambda t: np.array([5.0 * max(0.0, t - 57.0), 0.0, 0.0]) + (np.array([0, 40.0, 0]) if 20.0 < t < 20.1 else 0)
    fit = _pairs(noise_m=0.5, extra=pull).fit(np.inf, 20.0, 60.0)
    assert fit.dropped >= 20  # the last 3 s pulled up to 15 m, and the 40 m fix
    assert abs(fit.scale / SCALE - 1) < 0.01
    assert np.linalg.norm(fit.t_world_map - T_WORLD_MAP) < 1.0


def test_no_fit_says_why():
    assert _pairs(duration_s=0.5).fit(np.inf, 20.0, 60.0) == "5 GPS fixes paired with the visual map since it last jumped (at least 10 needed)"
    assert "short of 100 m" in _pairs().fit(np.inf, 100.0, 60.0)
    pairs = _pairs()
    pairs.clear()
    assert "0 GPS fixes" in pairs.fit(np.inf, 20.0, 60.0)


def test_fixes_are_paired_by_interpolation_and_not_across_a_pause():
    pairs = GpsMapPairs(np.eye(4))
    pose = np.eye(4)
    pairs.add_pose(1.0, pose)
    pairs.add_fix(1.05, np.array([1.0, 2.0, 3.0]))
    pose[:3, 3] = [0.1, 0.0, 0.0]
    pairs.add_pose(1.1, pose)
    assert len(pairs) == 1 and np.allclose(pairs.camera_positions[0], [0.05, 0.0, 0.0])
    pairs.add_fix(1.2, np.zeros(3))
    pairs.add_pose(2.0, pose)  # 0.9 s without a pose: tracking paused, the fix is not paired
    assert len(pairs) == 1


def test_only_the_newest_pairs_are_kept():
    fit = _pairs(max_span_s=20.0).fit(np.inf, 5.0, 60.0)
    assert 19.0 < fit.span_s <= 20.0 and fit.pairs <= 201
