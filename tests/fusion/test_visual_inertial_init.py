"""Visual-inertial initialisation on exact synthetic keyframes and IMU."""

import numpy as np

from evp.config import NavigationSettings

from evp.fusion.nav_state import so3_log
from evp.fusion.navigation_filter import NavigationFilter
from evp.fusion.visual_inertial_init import initialise_visual_inertial
from tests.fusion.inertial_trajectory import GRAVITY, SinusoidTrajectory, imu_times
from tests.fusion.test_navigation_filter import MAP_SCALE, R_WORLD_MAP, T_BODY_CAM, T_WORLD_MAP

GYRO_BIAS = np.array([0.003, -0.002, 0.004])


def keyframes(trajectory, times):
    out = []
    for t in times:
        T_world_cam = trajectory.pose(t) @ T_BODY_CAM
        T = np.eye(4)
        T[:3, :3] = R_WORLD_MAP.T @ T_world_cam[:3, :3]
        T[:3, 3] = R_WORLD_MAP.T @ (T_world_cam[:3, 3] - T_WORLD_MAP) / MAP_SCALE
        out.append((float(t), T))
    return out


# an IMU known to be unbiased: the scale's sigma need not allow for an accelerometer bias
KNOWN_UNBIASED = NavigationSettings(vi_init_accel_bias_sigma=0.0)


def test_gravity_scale_velocity_and_gyro_bias_are_recovered():
    trajectory = SinusoidTrajectory()
    imu = trajectory.imu(imu_times(4.0), GYRO_BIAS)
    frames = keyframes(trajectory, np.arange(0.0, 4.0001, 0.25))
    result = initialise_visual_inertial(frames, imu, T_BODY_CAM, KNOWN_UNBIASED)
    assert result.observable, result.reason
    assert abs(result.scale / MAP_SCALE - 1.0) < 0.01
    gravity_map = R_WORLD_MAP.T @ [0.0, 0.0, -GRAVITY]
    assert np.degrees(np.arccos(result.gravity_map @ gravity_map / GRAVITY**2)) < 0.5
    assert np.linalg.norm(result.gyro_bias - GYRO_BIAS) < 1e-4
    assert np.linalg.norm(result.velocities_map[-1] - R_WORLD_MAP.T @ trajectory.velocity(4.0)) < 0.02
    # the filter starts from it: gravity-aligned, at the estimated scale, with the map anchored
    start = result.nav_state(4.0, frames[-1][1], T_BODY_CAM, result.velocities_map[-1])
    tilt = so3_log(start.R_world_body @ trajectory.rotation(4.0).T)[:2]  # heading is the map's
    assert np.degrees(np.linalg.norm(tilt)) < 0.5 and start.map_anchored
    assert abs(NavigationFilter(start).output().scale - result.scale) < 1e-12


def test_constant_velocity_is_not_observable():
    trajectory = SinusoidTrajectory(amplitude=(0.0, 0.0, 0.0), cruise=(1.0, 0.5, 0.2))  # rotating, not accelerating
    result = initialise_visual_inertial(keyframes(trajectory, np.arange(0.0, 4.0001, 0.25)), trajectory.imu(imu_times(4.0)), T_BODY_CAM)
    assert not result.observable and "too little acceleration" in result.reason
    assert np.isnan(result.scale)


def test_too_few_keyframes_or_no_imu_is_not_observable():
    trajectory = SinusoidTrajectory()
    frames = keyframes(trajectory, [0.0, 0.5, 1.0])
    assert "too few keyframes" in initialise_visual_inertial(frames, trajectory.imu(imu_times(1.0)), T_BODY_CAM).reason
    frames = keyframes(trajectory, np.arange(0.0, 4.0001, 0.25))
    assert "do not span" in initialise_visual_inertial(frames, trajectory.imu(imu_times(2.0)), T_BODY_CAM).reason


def test_a_scale_an_accelerometer_bias_could_move_is_not_yet_determined():
    """The linear alignment leaves the accelerometer bias out; an IMU with 0.1 m/s^2 of it reads
    the stage's window (10 keyframes, 2.25 s) of the sinusoid's motion 12 % off. Its sigma includes
    what a bias of ``vi_init_accel_bias_sigma`` could do (19 % here), so the start waits; an IMU
    known to be unbiased starts, off by the bias."""
    trajectory = SinusoidTrajectory()
    frames = keyframes(trajectory, np.arange(0.0, 2.2501, 0.25))
    biased = trajectory.imu(imu_times(2.26), GYRO_BIAS, accel_bias=(0.1, -0.1, 0.1))
    trusting = initialise_visual_inertial(frames, biased, T_BODY_CAM, KNOWN_UNBIASED)
    assert trusting.observable and abs(trusting.scale / MAP_SCALE - 1.0) > 0.1  # the bias, read as scale
    careful = initialise_visual_inertial(frames, biased, T_BODY_CAM)
    assert not careful.observable and "scale not yet determined" in careful.reason


def test_a_newest_keyframe_between_two_imu_samples_is_solved_at_once():
    """A 30 Hz camera and a 200 Hz IMU rarely share a timestamp: the newest keyframe a few ms
    after the newest sample is spanned (that reading held), one a whole period later is not."""
    trajectory = SinusoidTrajectory()
    imu = trajectory.imu(imu_times(4.0), GYRO_BIAS)
    period = imu[1].timestamp - imu[0].timestamp
    within = keyframes(trajectory, [*np.arange(0.0, 3.9, 0.25), 4.0 + 0.6 * period])
    result = initialise_visual_inertial(within, imu, T_BODY_CAM, KNOWN_UNBIASED)
    assert result.observable, result.reason
    assert abs(result.scale / MAP_SCALE - 1.0) < 0.01
    beyond = keyframes(trajectory, [*np.arange(0.0, 3.9, 0.25), 4.0 + 1.5 * period])
    assert "do not span" in initialise_visual_inertial(beyond, imu, T_BODY_CAM, KNOWN_UNBIASED).reason
