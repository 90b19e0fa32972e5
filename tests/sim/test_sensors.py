"""Sensor noise statistics match their configuration; spoofing and outages start when configured."""

import numpy as np
import pymap3d
import pytest
from scipy.spatial.transform import Rotation

from evp.atmosphere import altitude_from_pressure, pressure_from_altitude
from evp.sim import sensors
from evp.sim.motion import SplineMotion

ORIGIN = (43.7, 10.4, 4.0)


def _still(duration: float) -> SplineMotion:
    times = np.linspace(0.0, duration, 50)
    return SplineMotion(times, np.tile([1.0, 2.0, 30.0], (50, 1)), Rotation.identity(50))


def test_imu_white_noise_and_bias_random_walk_match_the_densities():
    config = sensors.ImuConfig(gyro_bias_sigma=0.0, accel_bias_sigma=0.0, gyro_random_walk=0.0, accel_random_walk=0.0)
    state = _still(100.0).state(sensors.sample_times(0, 100, config.rate_hz))
    imu = sensors.simulate_imu(state, config, np.random.default_rng(0))
    gyro = np.array([s.angular_velocity_rad_s for s in imu.samples])
    accel = np.array([s.linear_acceleration_m_s2 for s in imu.samples])
    dt = 1 / config.rate_hz
    assert gyro.std(axis=0) == pytest.approx([config.gyro_noise_density / np.sqrt(dt)] * 3, rel=0.03)
    assert accel.std(axis=0) == pytest.approx([config.accel_noise_density / np.sqrt(dt)] * 3, rel=0.03)
    assert accel.mean(axis=0) == pytest.approx([0, 0, 9.80665], abs=0.01)  # level and still: gravity up
    walk = sensors.ImuConfig(gyro_noise_density=0, accel_noise_density=0, gyro_bias_sigma=0, accel_bias_sigma=0)
    imu = sensors.simulate_imu(state, walk, np.random.default_rng(1))
    steps = np.diff(imu.gyro_bias, axis=0)
    assert steps.std(axis=0) == pytest.approx([walk.gyro_random_walk * np.sqrt(dt)] * 3, rel=0.03)
    assert np.diff(imu.accel_bias, axis=0).std() == pytest.approx(walk.accel_random_walk * np.sqrt(dt), rel=0.03)


def test_ideal_imu_integrates_back_to_the_trajectory():
    """Specific force and body rates are consistent with the motion (signs, frames, gravity)."""
    from evp.sim.scenarios import SimOptions, build_scenario

    scenario = build_scenario("hover-drift", SimOptions(duration_s=30.0))
    times = sensors.sample_times(5.0, 15.0, 1000.0)
    state = scenario.motion.state(times)
    ideal = sensors.ImuConfig(gyro_noise_density=0, accel_noise_density=0, gyro_random_walk=0, accel_random_walk=0, gyro_bias_sigma=0, accel_bias_sigma=0)
    imu = sensors.simulate_imu(state, ideal, np.random.default_rng(0))
    R = state.rotation[0]
    p, v = state.position[0].copy(), state.velocity[0].copy()
    dt = times[1] - times[0]
    gravity = np.array([0, 0, -9.80665])
    for k in range(len(times) - 1):
        w0, w1 = np.array(imu.samples[k].angular_velocity_rad_s), np.array(imu.samples[k + 1].angular_velocity_rad_s)
        f0 = np.array(imu.samples[k].linear_acceleration_m_s2)
        R_next = R * Rotation.from_rotvec(0.5 * (w0 + w1) * dt)
        f1 = np.array(imu.samples[k + 1].linear_acceleration_m_s2)
        a = 0.5 * (R.apply(f0) + R_next.apply(f1)) + gravity
        p += v * dt + 0.5 * a * dt * dt
        v += a * dt
        R = R_next
    assert np.linalg.norm(p - state.position[-1]) < 0.01
    assert (R.inv() * state.rotation[-1]).magnitude() < 1e-3


def _gps_enu(fixes):
    lat, lon, alt = (np.array([getattr(f, k) for f in fixes]) for k in ("latitude_deg", "longitude_deg", "altitude_m"))
    return np.column_stack(pymap3d.geodetic2enu(lat, lon, alt, *ORIGIN))


def test_gps_error_statistics_match_sigma():
    config = sensors.GpsConfig(horizontal_sigma_m=2.0, vertical_sigma_m=4.0, correlation_time_s=5.0)
    state = _still(4000.0).state(sensors.sample_times(0, 4000, config.rate_hz))
    errors = _gps_enu(sensors.simulate_gps(state, config, ORIGIN, np.random.default_rng(0))) - state.position
    assert np.std(errors[:, :2]) == pytest.approx(2.0 / np.sqrt(2), rel=0.1)
    assert np.std(errors[:, 2]) == pytest.approx(4.0, rel=0.1)
    assert abs(errors.mean(axis=0)).max() < 0.3
    lag = int(config.correlation_time_s * config.rate_hz)
    correlated = np.corrcoef(errors[:-lag, 0], errors[lag:, 0])[0, 1]
    assert correlated == pytest.approx((1 - config.white_fraction) * np.exp(-1), abs=0.1)


def test_spoofing_pull_off_and_jump_start_when_configured():
    state = _still(100.0).state(sensors.sample_times(0, 100, 10.0))
    quiet = dict(horizontal_sigma_m=0.0, vertical_sigma_m=0.0)
    pull = sensors.GpsConfig(**quiet, spoof_start_s=40.0, spoof_mode="pull", spoof_rate_m_s=5.0, spoof_direction_deg=90.0)
    enu = _gps_enu(sensors.simulate_gps(state, pull, ORIGIN, np.random.default_rng(0)))
    offset = enu - state.position
    before, after = state.time < 40.0, state.time >= 40.0
    assert np.abs(offset[before]).max() < 1e-6
    assert offset[after, 1] == pytest.approx(5.0 * (state.time[after] - 40.0), abs=1e-6)  # north, growing at 5 m/s
    jump = sensors.GpsConfig(**quiet, spoof_start_s=40.0, spoof_mode="jump", spoof_jump_m=50.0)
    offset = _gps_enu(sensors.simulate_gps(state, jump, ORIGIN, np.random.default_rng(0))) - state.position
    assert np.abs(offset[before]).max() < 1e-6
    assert offset[after, 0] == pytest.approx(50.0, abs=1e-6)


def test_jamming_outages_and_clock_offset():
    state = _still(100.0).state(sensors.sample_times(0, 100, 10.0))
    config = sensors.GpsConfig(outages=[(20.0, 60.0)], clock_offset_s=0.4)
    fixes = sensors.simulate_gps(state, config, ORIGIN, np.random.default_rng(0))
    stamps = np.array([f.timestamp for f in fixes]) - 0.4
    assert not np.any((stamps >= 20.0 - 1e-9) & (stamps < 80.0 - 1e-9))
    assert len(fixes) == len(state.time) - 600
    assert stamps[0] == pytest.approx(0.0)


def test_barometer_noise_and_drift():
    config = sensors.BaroConfig(noise_m=0.5, drift_m_per_min=1.2)
    state = _still(600.0).state(sensors.sample_times(0, 600, config.rate_hz))
    samples = sensors.simulate_baro(state, config, ORIGIN[2], np.random.default_rng(0))
    altitude = np.array([s.altitude_m for s in samples]) - ORIGIN[2] - 30.0
    slope, intercept = np.polyfit(state.time, altitude, 1)
    assert slope * 60 == pytest.approx(1.2, rel=0.02)
    assert np.std(altitude - (slope * state.time + intercept)) == pytest.approx(0.5, rel=0.05)
    pressure = np.array([s.pressure_pa for s in samples])
    assert pressure[0] == pytest.approx(pressure_from_altitude(np.array([34.0]))[0], abs=20)  # ~12 Pa per metre
    assert altitude_from_pressure(pressure_from_altitude(np.array([34.0]))) == pytest.approx([34.0])


def test_wheel_odometry_quantisation_and_gyro():
    times = np.linspace(0, 20, 100)
    yaw = 0.2 * times
    positions = np.column_stack([np.sin(yaw) / 0.2 * 0.5, (1 - np.cos(yaw)) / 0.2 * 0.5, np.zeros(100)])  # 0.5 m/s arc
    motion = SplineMotion(times, positions, Rotation.from_euler("z", yaw[:, None]))
    config = sensors.WheelConfig(speed_noise_m_s=0.0, gyro_noise_rad_s=0.001, gyro_bias_rad_s=0.0)
    state = motion.state(sensors.sample_times(2, 18, config.rate_hz))
    samples = sensors.simulate_wheels(state, config, np.random.default_rng(0))
    quantum = 2 * np.pi * config.wheel_radius_m / config.ticks_per_rev * config.rate_hz
    left = np.array([s.wheel_speeds_m_s[0] for s in samples])
    assert np.allclose(left / quantum, np.round(left / quantum))
    forward = np.array([s.forward_speed_m_s for s in samples])
    assert np.mean(forward) == pytest.approx(0.5, abs=quantum / len(forward))  # ticks carried over: unbiased
    gyro = np.array([s.yaw_rate_rad_s for s in samples])
    assert np.mean(gyro) == pytest.approx(0.2, abs=1e-3) and np.std(gyro) == pytest.approx(0.001, rel=0.15)


def test_wifi_shadowing_and_range_noise():
    config = sensors.WifiConfig(shadowing_db=4.0)
    state = _still(2000.0).state(sensors.sample_times(0, 2000, config.rate_hz))
    access_points = np.array([[0.0, 0.0, 30.0], [11.0, 2.0, 30.0]])
    scans = sensors.simulate_wifi(state, config, access_points, np.random.default_rng(0))
    rss = np.array([list(s.rssi_dbm.values()) for s in scans])
    expected = config.p0_dbm - 10 * config.path_loss_exponent * np.log10(np.linalg.norm(access_points - [1.0, 2.0, 30.0], axis=1))
    assert rss.mean(axis=0) == pytest.approx(expected, abs=0.4)
    assert rss.std(axis=0) == pytest.approx([4.0, 4.0], rel=0.08)
    ranging = sensors.RangeConfig(noise_m=0.02, max_range_m=40.0)
    state = _still(100.0).state(sensors.sample_times(0, 100, ranging.rate_hz))
    readings = np.array([s.distance_m for s in sensors.simulate_range(state, ranging, lambda p, d: p[2], np.random.default_rng(0))])
    assert readings.mean() == pytest.approx(30.0, abs=0.005) and readings.std() == pytest.approx(0.02, rel=0.1)
    short = sensors.RangeConfig(max_range_m=5.0)
    assert np.isnan(sensors.simulate_range(state, short, lambda p, d: p[2], np.random.default_rng(0))[0].distance_m)
