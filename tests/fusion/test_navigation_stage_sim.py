"""The navigation stage on the simulator's scenarios, without rendering: the scenario's own motion
gives exact IMU samples and wheel records (noise off) and the camera poses, which enter the stage
in a visual map of arbitrary frame and scale, as SLAM's would."""

import numpy as np

from evp.config import NavigationSettings
from evp.fusion.navigation_stage import NavigationStage
from evp.pipeline import run_frames
from evp.sim import sensors
from evp.sim.scenarios import SimOptions, build_scenario
from evp.types import PoseEstimate, TrackingState
from tests.fusion.test_navigation_stage import _Answers, _frames

FRAME_RATE = 20.0
MAP_SCALE = 0.37  # metres per map unit
EXACT_IMU = sensors.ImuConfig(gyro_noise_density=0, gyro_random_walk=0, gyro_bias_sigma=0, accel_noise_density=0, accel_random_walk=0, accel_bias_sigma=0)
EXACT_WHEELS = sensors.WheelConfig(speed_noise_m_s=0, gyro_noise_rad_s=0, gyro_bias_rad_s=0)


def _run_scenario(name: str, duration_s: float, settings: NavigationSettings, wheels: bool, until_s: float = np.inf, position_noise_m: float = 0.0):
    """The stage over the scenario's frames up to ``until_s``, the camera positions with white
    noise of ``position_noise_m`` (metres, 1 sigma) as SLAM's have."""
    scenario = build_scenario(name, SimOptions(duration_s=duration_s))
    start, end = scenario.motion.start, scenario.motion.end
    times = np.arange(start, min(end, until_s), 1.0 / FRAME_RATE)
    T_world_map = scenario.camera_poses(times[:1])[0]  # the map's frame: the first camera's, scaled
    T_map_world = np.linalg.inv(T_world_map)
    estimates = []
    noise = np.random.default_rng(1).normal(0.0, position_noise_m, (len(times), 3))
    for t, T_world_cam, error in zip(times, scenario.camera_poses(times), noise):
        T = T_map_world @ T_world_cam
        T[:3, 3] = (T[:3, 3] + error) / MAP_SCALE
        estimates.append(PoseEstimate(float(t), T, TrackingState.OK, 80))
    imu = sensors.simulate_imu(scenario.motion.state(sensors.sample_times(start, end, 200.0)), EXACT_IMU, np.random.default_rng(0)).samples
    telemetry = list(imu)
    if wheels:
        telemetry += sensors.simulate_wheels(scenario.motion.state(sensors.sample_times(start, end, 50.0)), EXACT_WHEELS, np.random.default_rng(0))
    telemetry.sort(key=lambda record: record.timestamp)
    estimator = _Answers(estimates)
    stage = NavigationStage(scenario.T_body_cam, settings, lambda: estimator.reset_counter)
    result = run_frames(estimator, _frames(times), stages=[stage], telemetry=telemetry)
    return stage, result


def test_wheel_odometry_makes_the_scale_known_without_imu_excitation():
    # the visual-inertial initialisation made unreachable: only the wheels can give the scale
    settings = NavigationSettings(vi_init_min_acceleration_std_m_s2=100.0)
    stage, result = _run_scenario("wheel-robot-room", 8.0, settings, wheels=True)
    assert stage.filter is not None, stage.status
    assert "from wheel odometry" in stage.status
    assert stage.initialised_at < 5.0  # the robot stands 2 s, then the wheels cover 0.3 m in about 1 s more
    assert abs(stage.alignment.scale / MAP_SCALE - 1.0) < 0.02
    assert {"wheels", "yaw_rate", "visual"} <= stage.sensors_used
    final = stage.records[-1].output
    assert final.scale_known and abs(final.scale / MAP_SCALE - 1.0) < 0.01
    # without the wheels the same run never starts, and says why
    stage, result = _run_scenario("wheel-robot-room", 8.0, settings.model_copy(update={"use_wheels": False}), wheels=True)
    assert stage.filter is None and stage.status.startswith("scale not yet observable")
    assert not any(e.metric for e in result.estimates)


def test_the_circle_standing_start_is_not_observable_then_is():
    # the walker stands (swaying by hand) for 2 s before walking the circle: with SLAM's centimetre
    # noise the sway cannot give the scale (the rendered circle's start took 0.39 m/unit for 1.26)
    noisy = {"wheels": False, "until_s": 1.9, "position_noise_m": 0.01}
    stage, result = _run_scenario("circle-indoor", 8.0, NavigationSettings(), **noisy)
    assert stage.filter is None and "scale not yet determined" in stage.status, stage.status
    assert not any(e.metric for e in result.estimates)
    # exact poses and an IMU known to be unbiased: the sway's 0.3 m/s^2 is excitation enough, the
    # scale is right at once
    stage, result = _run_scenario("circle-indoor", 8.0, NavigationSettings(vi_init_accel_bias_sigma=0.0), wheels=False)
    assert stage.filter is not None, stage.status
    assert stage.initialised_at <= 1.0, stage.status
    assert "from visual-inertial" in stage.status
    assert abs(stage.alignment.scale / MAP_SCALE - 1.0) < 0.01
    assert not any(e.metric for e in result.estimates if e.timestamp < stage.initialised_at)
    # the scale is right; its sigma (the flag scale_known) still shrinks slowly here: the circle's
    # 0.1 m/s^2 centripetal acceleration is constant in the body frame, like an accelerometer bias
    assert abs(stage.records[-1].output.scale / MAP_SCALE - 1.0) < 0.01
    # with the default bias prior the sway could as well be a bias: the start waits for the walk
    stage, result = _run_scenario("circle-indoor", 8.0, NavigationSettings(), wheels=False)
    assert stage.filter is not None and 2.0 < stage.initialised_at <= 4.0, stage.status
    assert abs(stage.records[-1].output.scale / MAP_SCALE - 1.0) < 0.01
