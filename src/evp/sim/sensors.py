"""Sensor models with documented, configurable noise, sampled along a :class:`MotionState`.

Every model draws from its own seeded generator, so one sensor's settings never change another
sensor's noise. Defaults are typical phone / small-drone values; the docstrings say the model.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pymap3d
from pydantic import BaseModel, ConfigDict, Field

from evp.atmosphere import pressure_from_altitude
from evp.sim.motion import MotionState
from evp.types import BaroSample, GpsFix, ImuSample, RangeSample, WheelOdometry, WifiScan
from evp.wifi.fingerprints import Fingerprints


class _Config(BaseModel):
    model_config = ConfigDict(extra="forbid")


class ImuConfig(_Config):
    """Continuous-time white noise densities and bias random walks (Kalibr/EuRoC convention):
    per sample the white noise has sigma = density / sqrt(dt); the bias moves by
    random_walk * sqrt(dt) * N(0, 1) each step, starting from N(0, initial bias sigma)."""

    rate_hz: float = Field(200.0, gt=0)
    gyro_noise_density: float = Field(1.7e-4, ge=0, description="rad/s/sqrt(Hz)")
    gyro_random_walk: float = Field(1.9e-5, ge=0, description="rad/s^2/sqrt(Hz)")
    gyro_bias_sigma: float = Field(0.005, ge=0, description="rad/s, initial bias")
    accel_noise_density: float = Field(2.0e-3, ge=0, description="m/s^2/sqrt(Hz)")
    accel_random_walk: float = Field(3.0e-3, ge=0, description="m/s^3/sqrt(Hz)")
    accel_bias_sigma: float = Field(0.05, ge=0, description="m/s^2, initial bias")


class GpsConfig(_Config):
    """Fixes at ``rate_hz`` on the GPS clock (true time + ``clock_offset_s``). Error = first-order
    Gauss-Markov (sigma, correlation time) + white noise. Jamming: no fixes inside ``outages``
    (start, duration) windows. Spoofing from ``spoof_start_s``: a pull-off growing at
    ``spoof_rate_m_s`` along ``spoof_direction_deg`` (ENU, from east), or a ``spoof_jump_m`` step."""

    rate_hz: float = Field(10.0, gt=0)
    horizontal_sigma_m: float = Field(1.5, ge=0)
    vertical_sigma_m: float = Field(3.0, ge=0)
    correlation_time_s: float = Field(60.0, gt=0)
    white_fraction: float = Field(0.3, ge=0, le=1, description="share of the variance that is white")
    clock_offset_s: float = Field(0.0, description="GPS clock minus camera clock")
    outages: list[tuple[float, float]] = Field(default_factory=list, description="(start s, duration s) of jamming")
    spoof_start_s: float | None = None
    spoof_mode: str = Field("pull", pattern="^(pull|jump)$")
    spoof_rate_m_s: float = Field(5.0, ge=0)
    spoof_jump_m: float = Field(50.0, ge=0)
    spoof_direction_deg: float = 0.0


class BaroConfig(_Config):
    """ISA pressure of the true altitude plus a linear drift and white noise (both in metres)."""

    rate_hz: float = Field(25.0, gt=0)
    noise_m: float = Field(0.3, ge=0)
    drift_m_per_min: float = Field(0.5)


class WheelConfig(_Config):
    """Differential drive: left/right wheel speeds from the body velocity and yaw rate, with white
    noise, as an encoder reports them: the ticks counted in each sample's interval (the count
    carries its remainder over, so the speeds are multiples of one tick per interval and their
    mean is unbiased); the yaw rate comes from a gyro with bias and noise."""

    rate_hz: float = Field(50.0, gt=0)
    wheel_base_m: float = Field(0.3, gt=0)
    wheel_radius_m: float = Field(0.035, gt=0)
    ticks_per_rev: int = Field(360, gt=0)
    speed_noise_m_s: float = Field(0.005, ge=0)
    gyro_noise_rad_s: float = Field(0.003, ge=0)
    gyro_bias_rad_s: float = Field(0.002)


class RangeConfig(_Config):
    """Distance along the body's down axis to the first surface (sonar / laser range finder)."""

    rate_hz: float = Field(20.0, gt=0)
    noise_m: float = Field(0.01, ge=0)
    max_range_m: float = Field(5.0, gt=0)


class WifiConfig(_Config):
    """RSS from access points: log-distance path loss P = P0 - 10 n log10(d / 1 m) + shadowing,
    shadowing ~ N(0, sigma) per scan (seed 001's fingerprinting set-up)."""

    rate_hz: float = Field(1.0, gt=0)
    access_points: int = Field(3, ge=1)
    p0_dbm: float = -40.0
    path_loss_exponent: float = Field(2.5, gt=0)
    shadowing_db: float = Field(4.0, ge=0)
    survey_spacing_m: float = Field(0.5, gt=0, description="the radio map's survey grid: nodes this far apart over the path's extent and 0.5 m around it")
    survey_samples: int = Field(20, ge=1, description="scans per survey node (seed 001 averaged ~100; 20 leave 0.9 dB of the 4 dB shadowing)")


def sample_times(start: float, end: float, rate_hz: float) -> np.ndarray:
    return start + np.arange(0.0, end - start + 1e-9, 1.0 / rate_hz)


@dataclass(frozen=True)
class ImuSimulation:
    samples: list[ImuSample]
    gyro_bias: np.ndarray  # (N, 3) true bias at each sample, rad/s
    accel_bias: np.ndarray  # (N, 3) m/s^2


def simulate_imu(state: MotionState, config: ImuConfig, rng: np.random.Generator) -> ImuSimulation:
    n = len(state.time)
    dt = 1.0 / config.rate_hz
    gyro_bias = rng.normal(0, config.gyro_bias_sigma, 3) + np.cumsum(rng.normal(0, config.gyro_random_walk * math.sqrt(dt), (n, 3)), axis=0)
    accel_bias = rng.normal(0, config.accel_bias_sigma, 3) + np.cumsum(rng.normal(0, config.accel_random_walk * math.sqrt(dt), (n, 3)), axis=0)
    gyro = state.body_rate + gyro_bias + rng.normal(0, config.gyro_noise_density / math.sqrt(dt), (n, 3))
    accel = state.specific_force_body() + accel_bias + rng.normal(0, config.accel_noise_density / math.sqrt(dt), (n, 3))
    samples = [ImuSample(float(t), tuple(map(float, g)), tuple(map(float, a))) for t, g, a in zip(state.time, gyro, accel)]
    return ImuSimulation(samples, gyro_bias, accel_bias)


def gps_errors(times: np.ndarray, config: GpsConfig, rng: np.random.Generator) -> np.ndarray:
    """(N, 3) ENU errors: Gauss-Markov + white, with the configured total sigmas."""
    sigma = np.array([config.horizontal_sigma_m / math.sqrt(2)] * 2 + [config.vertical_sigma_m])
    correlated_sigma = sigma * math.sqrt(1 - config.white_fraction)
    white_sigma = sigma * math.sqrt(config.white_fraction)
    errors = np.zeros((len(times), 3))
    state = rng.normal(0, correlated_sigma)
    for k in range(len(times)):
        if k:
            phi = math.exp(-(times[k] - times[k - 1]) / config.correlation_time_s)
            state = phi * state + rng.normal(0, correlated_sigma * math.sqrt(1 - phi * phi))
        errors[k] = state
    return errors + rng.normal(0, white_sigma, errors.shape)


def spoof_offsets(times: np.ndarray, config: GpsConfig) -> np.ndarray:
    """(N, 3) ENU offset the spoofer adds at each true time."""
    offsets = np.zeros((len(times), 3))
    if config.spoof_start_s is None:
        return offsets
    direction = np.array([math.cos(math.radians(config.spoof_direction_deg)), math.sin(math.radians(config.spoof_direction_deg)), 0.0])
    elapsed = np.maximum(times - config.spoof_start_s, 0.0)
    active = times >= config.spoof_start_s
    magnitude = config.spoof_rate_m_s * elapsed if config.spoof_mode == "pull" else np.where(active, config.spoof_jump_m, 0.0)
    return magnitude[:, None] * direction


def simulate_gps(state: MotionState, config: GpsConfig, origin: tuple[float, float, float], rng: np.random.Generator) -> list[GpsFix]:
    """Fixes (no rows during outages), stamped on the GPS clock."""
    enu = state.position + gps_errors(state.time, config, rng) + spoof_offsets(state.time, config)
    lat, lon, alt = pymap3d.enu2geodetic(enu[:, 0], enu[:, 1], enu[:, 2], *origin)
    jammed = np.zeros(len(state.time), bool)
    for start, duration in config.outages:
        jammed |= (state.time >= start) & (state.time < start + duration)
    return [
        GpsFix(float(t + config.clock_offset_s), float(la), float(lo), float(al), config.horizontal_sigma_m, config.vertical_sigma_m)
        for t, la, lo, al, j in zip(state.time, lat, lon, alt, jammed)
        if not j
    ]


def simulate_baro(state: MotionState, config: BaroConfig, origin_alt_m: float, rng: np.random.Generator) -> list[BaroSample]:
    drift = config.drift_m_per_min * (state.time - state.time[0]) / 60.0
    altitude = origin_alt_m + state.position[:, 2] + drift + rng.normal(0, config.noise_m, len(state.time))
    pressure = pressure_from_altitude(altitude)
    return [BaroSample(float(t), float(p), float(a)) for t, p, a in zip(state.time, pressure, altitude)]


def _encoder(speed: np.ndarray, quantum: float) -> np.ndarray:
    """The speeds an encoder reports for these true ones: whole ticks counted per sample (one tick
    per sample is ``quantum`` m/s), the fraction of a tick carried over to the next sample.
    Rounding each sample's speed instead would bias a constant speed by up to half a tick."""
    ticks = np.floor(np.cumsum(speed / quantum) + 0.5)
    return np.diff(ticks, prepend=0.0) * quantum


def simulate_wheels(state: MotionState, config: WheelConfig, rng: np.random.Generator) -> list[WheelOdometry]:
    forward = np.einsum("ij,ij->i", state.rotation.inv().apply(state.velocity), np.tile([1.0, 0.0, 0.0], (len(state.time), 1)))
    yaw_rate = state.body_rate[:, 2]
    quantum = 2 * math.pi * config.wheel_radius_m / config.ticks_per_rev * config.rate_hz  # speed of one tick per sample
    left = forward - yaw_rate * config.wheel_base_m / 2 + rng.normal(0, config.speed_noise_m_s, len(forward))
    right = forward + yaw_rate * config.wheel_base_m / 2 + rng.normal(0, config.speed_noise_m_s, len(forward))
    left, right = _encoder(left, quantum), _encoder(right, quantum)
    gyro = yaw_rate + config.gyro_bias_rad_s + rng.normal(0, config.gyro_noise_rad_s, len(forward))
    return [WheelOdometry(float(t), (float(lw), float(rw)), float((lw + rw) / 2), float(g)) for t, lw, rw, g in zip(state.time, left, right, gyro)]


def simulate_wifi(state: MotionState, config: WifiConfig, access_points: np.ndarray, rng: np.random.Generator) -> list[WifiScan]:
    scans = []
    for t, p in zip(state.time, state.position):
        rss = _path_loss_rss(p[None], config, access_points, rng)[0]
        scans.append(WifiScan(float(t), {_bssid(i): float(r) for i, r in enumerate(rss)}))
    return scans


def _path_loss_rss(points: np.ndarray, config: WifiConfig, access_points: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """(N, A) dBm at ``points`` (N, 3): the log-distance model with fresh shadowing per scan."""
    distance = np.maximum(np.linalg.norm(points[:, None] - access_points[None], axis=2), 0.1)
    return config.p0_dbm - 10 * config.path_loss_exponent * np.log10(distance) + rng.normal(0, config.shadowing_db, distance.shape)


def simulate_wifi_survey(path: np.ndarray, config: WifiConfig, access_points: np.ndarray, rng: np.random.Generator) -> Fingerprints:
    """The survey a radio map is built from: ``survey_samples`` scans at each node of a grid of
    ``survey_spacing_m`` over the extent of ``path`` (N, 3) and 0.5 m around it, at the path's
    mean height (the phone's), floor 0; access points named as :func:`simulate_wifi` names them."""
    low, high = path[:, :2].min(axis=0) - 0.5, path[:, :2].max(axis=0) + 0.5
    xs, ys = (np.arange(lo, hi + 1e-9, config.survey_spacing_m) for lo, hi in zip(low, high))
    nodes = np.array([(x, y) for x in xs for y in ys]).repeat(config.survey_samples, axis=0)
    points = np.column_stack([nodes, np.full(len(nodes), path[:, 2].mean())])
    rss = _path_loss_rss(points, config, access_points, rng)
    return Fingerprints(rss, nodes, np.zeros(len(nodes), dtype=int), tuple(_bssid(i) for i in range(len(access_points))))


def _bssid(index: int) -> str:
    return f"02:00:00:00:00:{index:02x}"


def simulate_range(state: MotionState, config: RangeConfig, distance_along_down, rng: np.random.Generator) -> list[RangeSample]:
    """``distance_along_down(position, direction)`` gives the true distance to the scene."""
    down = state.rotation.apply(np.array([0.0, 0.0, -1.0]))
    samples = []
    for t, p, d in zip(state.time, state.position, down):
        distance = distance_along_down(p, d)
        reading = distance + rng.normal(0, config.noise_m) if distance <= config.max_range_m else float("nan")
        samples.append(RangeSample(float(t), float(reading)))
    return samples
