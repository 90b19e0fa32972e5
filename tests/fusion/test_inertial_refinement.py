"""The inertial-only maximum-likelihood refinement on exact synthetic keyframes and IMU: a known
scale, gravity and accelerometer bias are recovered where the linear alignment, which neglects
the bias, is off."""

import numpy as np

from evp.config import NavigationSettings
from evp.fusion.inertial_refinement import refine_inertial, white_position_noise
from evp.fusion.nav_state import so3_exp
from evp.fusion.visual_inertial_init import initialise_visual_inertial
from evp.types import PoseEstimate, TrackingState
from tests.fusion.inertial_trajectory import GRAVITY, SinusoidTrajectory, imu_times
from tests.fusion.test_navigation_filter import MAP_SCALE, R_WORLD_MAP, T_BODY_CAM
from tests.fusion.test_navigation_stage import FRAME_RATE, _run, map_pose
from tests.fusion.test_visual_inertial_init import GYRO_BIAS, keyframes

ACCEL_BIAS = np.array([0.08, -0.12, 0.05])
# the linear alignment's numbers, however uncertain (the stage seeds the refinement with them so)
ANY_SIGMA = NavigationSettings(vi_init_max_scale_sigma=1.0)


def _gravity_error_deg(gravity_map: np.ndarray) -> float:
    expected = R_WORLD_MAP.T @ [0.0, 0.0, -GRAVITY]
    return float(np.degrees(np.arccos(np.clip(gravity_map @ expected / GRAVITY**2, -1.0, 1.0))))


def test_scale_gravity_and_accelerometer_bias_are_recovered():
    trajectory = SinusoidTrajectory()
    imu = trajectory.imu(imu_times(4.0), GYRO_BIAS, ACCEL_BIAS)
    frames = keyframes(trajectory, np.arange(0.0, 4.0001, 0.25))
    linear = initialise_visual_inertial(frames, imu, T_BODY_CAM, ANY_SIGMA)
    assert linear.observable, linear.reason
    refined = refine_inertial(frames, imu, T_BODY_CAM, linear, visual_position_sigma_m=1e-4)
    assert refined.observable
    assert abs(refined.scale / MAP_SCALE - 1.0) < 0.002 < abs(linear.scale / MAP_SCALE - 1.0)
    assert np.linalg.norm(refined.accel_bias - ACCEL_BIAS) < 0.01
    assert _gravity_error_deg(refined.gravity_map) < 0.05
    assert np.linalg.norm(refined.velocities_map[-1] - R_WORLD_MAP.T @ trajectory.velocity(4.0)) < 0.005
    assert 0 < refined.scale_sigma < 0.01
    # the filter starts with the bias
    start = refined.nav_state(4.0, frames[-1][1], T_BODY_CAM, refined.velocities_map[-1])
    assert np.allclose(start.accel_bias, refined.accel_bias)


def test_noisy_visual_attitudes_are_replaced_by_the_gyros():
    """Visual attitudes 0.5 degree off at random leak 0.09 m/s^2 of gravity into each interval;
    the gyro-chained attitudes, fitted to all of them, do not."""
    trajectory = SinusoidTrajectory()
    imu = trajectory.imu(imu_times(4.0), GYRO_BIAS, ACCEL_BIAS)
    frames = keyframes(trajectory, np.arange(0.0, 4.0001, 0.25))
    rng = np.random.default_rng(3)
    noisy = []
    for t, T in frames:
        T = T.copy()
        T[:3, :3] = T[:3, :3] @ so3_exp(rng.normal(0.0, np.radians(0.5), 3))
        noisy.append((t, T))
    linear = initialise_visual_inertial(noisy, imu, T_BODY_CAM, ANY_SIGMA)
    refined = refine_inertial(noisy, imu, T_BODY_CAM, linear, visual_position_sigma_m=1e-4)
    assert abs(refined.scale / MAP_SCALE - 1.0) < 0.01 < abs(linear.scale / MAP_SCALE - 1.0)
    assert _gravity_error_deg(refined.gravity_map) < 1.0


def test_the_stage_starts_from_the_refined_alignment():
    """``navigation.vi_init_refine``: the filter starts once the refinement over every keyframe
    since the first has the scale within ``vi_refine_max_scale_sigma``, with its scale and bias."""
    trajectory = SinusoidTrajectory()
    times = np.arange(0.0, 3.0, 1.0 / FRAME_RATE)
    estimates = [PoseEstimate(float(t), map_pose(trajectory, t), TrackingState.OK, 80) for t in times]
    imu = trajectory.imu(imu_times(3.0), GYRO_BIAS, ACCEL_BIAS)
    settings = NavigationSettings(vi_init_refine=True, vi_refine_position_sigma_m=1e-4)
    stage, _ = _run(estimates, imu, settings=settings)
    assert stage.filter is not None, stage.status
    assert stage.alignment.scale_sigma <= settings.vi_refine_max_scale_sigma
    assert abs(stage.alignment.scale / MAP_SCALE - 1.0) < 0.01
    assert np.linalg.norm(stage.alignment.accel_bias - ACCEL_BIAS) < 0.05


def test_the_white_noise_of_a_track_is_measured_through_its_motion():
    """Per axis, from second differences at irregular frame times: the sinusoid's motion (its
    acceleration times dt^2 is 0.1 mm at 20 fps) does not count, a dropped frame does not either."""
    trajectory = SinusoidTrajectory()
    rng = np.random.default_rng(5)
    times = np.sort(rng.choice(np.arange(0.0, 10.0, 1.0 / FRAME_RATE), 150, replace=False))
    sigma = np.array([0.005, 0.01, 0.002])
    positions = np.array([trajectory.position(t) for t in times]) + rng.normal(0.0, 1.0, (len(times), 3)) * sigma
    measured = white_position_noise(times, positions)
    np.testing.assert_allclose(measured, sigma, rtol=0.25)
    assert white_position_noise(times[:7], positions[:7]) is None
    assert white_position_noise(np.r_[times[:5], times[4:10]], np.r_[positions[:5], positions[4:10]]) is None  # a repeated time
