"""A planar extended Kalman filter for a ground vehicle whose motion comes from wheel odometry
(forward speed and yaw rate), corrected by ranges to surveyed beacons and by GNSS positions.

State (SI units, world frame x east / y north or the dataset's own metric frame, yaw
counter-clockwise from +x):

====================  ====================================================================
x, y                  position (m)
yaw                   heading (rad)
speed scale           true forward speed / measured (1 = the wheels are right); estimated
                      when ``scale_sigma`` > 0 (tyre radius, CAN speed calibration)
yaw-rate bias         measured - true yaw rate (rad/s); estimated when
                      ``yaw_rate_bias_sigma_rad_s`` > 0 (a gyro's bias; wheel-derived yaw
                      rates have none worth a state)
range scale           measured / true range - 1, common to all beacons (a ranging clock that
                      runs fast or slow); estimated when ``range_scale_sigma`` > 0
range bias, each      measured - true range (m) per beacon (antenna delay, multipath);
beacon                estimated when ``range_bias_sigma_m`` > 0
====================  ====================================================================

Propagation: each odometry sample carries the mean speed and yaw rate over the interval since the
previous sample (what increments and wheel ticks give); the position moves along the heading at
the middle of that interval. The sample's own errors are independent from sample to sample, with
1-sigma ``speed_sigma_fraction`` x |speed| + ``speed_sigma_m_s`` and ``yaw_rate_sigma_rad_s``;
the calibration states drift as random walks.

Updates are fused at their own time: a range or fix newer than the filter waits until the
odometry sample that covers its time arrives, the interval is split there, and the update is
applied in between. One older than the filter (late by at most ``max_delay_s``) is applied at
the filter's time; an older one is dropped with a warning. Each update passes a chi-square gate
(``gate_probability`` of a consistent measurement passes) and leaves an :class:`Innovation`
record whether it was accepted or not. Bad records (NaN, an unknown beacon, time going
backwards) are skipped with a warning in ``warnings``; nothing already fused is lost.

The noise values belong to the sensors and are given by the caller with their source (data
sheets, the dataset's README, a few seconds measured at the start); nothing here is tuned.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from evp.fusion.geodesy import EnuFrame
from evp.fusion.innovation import Innovation, gated_innovation
from evp.fusion.planar_motion import unicycle_step
from evp.types import BeaconRange, GpsFix, WheelOdometry

X, Y, YAW, SCALE, BIAS, RANGE_SCALE = range(6)
BASE_STATES = 6


@dataclass(frozen=True)
class OdometryNoise:
    """1-sigma noise of the inputs and measurements, and the priors of the calibration states
    (a prior of 0 keeps that state out of the estimate). Units in the names."""

    speed_sigma_fraction: float
    speed_sigma_m_s: float
    yaw_rate_sigma_rad_s: float
    range_sigma_m: float = 1.0
    gnss_sigma_m: float = 3.0
    scale_sigma: float = 0.0
    scale_walk_per_sqrt_s: float = 0.0
    yaw_rate_bias_sigma_rad_s: float = 0.0
    yaw_rate_bias_walk_rad_s_per_sqrt_s: float = 0.0
    range_bias_sigma_m: float = 0.0
    range_bias_walk_m_per_sqrt_s: float = 0.0
    range_scale_sigma: float = 0.0
    gate_probability: float = 0.9973  # the 3-sigma share of a Gaussian, for any number of dimensions
    max_delay_s: float = 0.5  # a measurement later than this behind the filter is dropped


@dataclass(frozen=True)
class PlanarPose:
    """A start pose: position (m), heading (rad) and their 1-sigma uncertainties."""

    x: float
    y: float
    yaw: float
    position_sigma_m: float = 0.1
    yaw_sigma_rad: float = 0.05


@dataclass(frozen=True)
class PlanarState:
    """The filter's estimate at ``timestamp``; ``covariance`` is over the full state vector in
    the order of the module docstring (beacons in ``range_biases_m``'s order)."""

    timestamp: float
    x: float
    y: float
    yaw: float
    speed_scale: float
    yaw_rate_bias_rad_s: float
    range_scale: float
    range_biases_m: dict[str, float]
    covariance: np.ndarray

    @property
    def position_covariance(self) -> np.ndarray:
        return self.covariance[:2, :2]


@dataclass(frozen=True)
class _Pending:
    timestamp: float
    order: int
    record: BeaconRange | GpsFix


@dataclass
class OdometryFilter:
    """The filter. Feed it time-ordered records with :meth:`add` (odometry, beacon ranges, GNSS
    fixes); read :meth:`state` after any of them. ``gnss_frame`` puts fixes into the world frame
    (needed only when fixes are given)."""

    noise: OdometryNoise
    start: PlanarPose
    start_time: float
    beacons: dict[str, tuple[float, float, float]] = field(default_factory=dict)
    gnss_frame: EnuFrame | None = None
    initial_range_bias_m: float = 0.0
    antenna_height_m: float = 0.0
    innovations: list[Innovation] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)

    def __post_init__(self) -> None:
        self.beacon_ids = list(self.beacons)
        n = BASE_STATES + len(self.beacon_ids)
        self.x = np.zeros(n)
        self.x[[X, Y, YAW, SCALE]] = self.start.x, self.start.y, self.start.yaw, 1.0
        self.x[BASE_STATES:] = self.initial_range_bias_m
        sigmas = [self.start.position_sigma_m] * 2 + [
            self.start.yaw_sigma_rad,
            self.noise.scale_sigma,
            self.noise.yaw_rate_bias_sigma_rad_s,
            self.noise.range_scale_sigma,
        ]
        sigmas += [self.noise.range_bias_sigma_m] * len(self.beacon_ids)
        self.P = np.diag(np.square(sigmas))
        self.time = float(self.start_time)
        self._pending: list[_Pending] = []
        self._count = 0
        self._warned: set[str] = set()

    # ---- input ---------------------------------------------------------------------------------

    def add(self, record: WheelOdometry | BeaconRange | GpsFix) -> None:
        """Fuse one record (see the module docstring for timing and bad records)."""
        if isinstance(record, WheelOdometry):
            self._odometry(record)
            return
        if isinstance(record, BeaconRange):
            if record.beacon_id not in self.beacons:
                self._warn(f"range to beacon {record.beacon_id!r} not in the beacon list ({', '.join(self.beacon_ids)}): skipped")
                return
            if not (math.isfinite(record.range_m) and record.range_m > 0):
                self._warn(f"range {record.range_m!r} to beacon {record.beacon_id!r} is not a finite positive number: skipped")
                return
        elif isinstance(record, GpsFix):
            if self.gnss_frame is None:
                raise ValueError("GNSS fixes need the filter's gnss_frame (the world frame's ENU origin)")
            if not all(math.isfinite(v) for v in (record.latitude_deg, record.longitude_deg)):
                self._warn("GNSS fix without a position (NaN): skipped")
                return
        else:
            raise TypeError(f"the odometry filter takes WheelOdometry, BeaconRange and GpsFix, not {type(record).__name__}")
        if not math.isfinite(record.timestamp):
            self._warn(f"{type(record).__name__} without a finite timestamp: skipped")
        elif record.timestamp <= self.time:
            if self.time - record.timestamp > self.noise.max_delay_s:
                self._warn(f"{type(record).__name__} more than {self.noise.max_delay_s} s older than the filter: skipped")
            else:
                self._update(record)
        else:
            self._pending.append(_Pending(record.timestamp, self._count, record))
            self._count += 1

    def state(self) -> PlanarState:
        biases = {name: float(self.x[BASE_STATES + i]) for i, name in enumerate(self.beacon_ids)}
        yaw = math.remainder(float(self.x[YAW]), 2 * math.pi)
        return PlanarState(
            self.time, float(self.x[X]), float(self.x[Y]), yaw, float(self.x[SCALE]), float(self.x[BIAS]), float(self.x[RANGE_SCALE]), biases, self.P.copy()
        )

    # ---- propagation ---------------------------------------------------------------------------

    def _odometry(self, sample: WheelOdometry) -> None:
        speed, rate = sample.forward_speed_m_s, sample.yaw_rate_rad_s
        if not all(math.isfinite(v) for v in (sample.timestamp, speed, rate)):
            self._warn("odometry sample without a finite time, forward speed or yaw rate: skipped")
            return
        if sample.timestamp == self.time:
            return  # an empty interval (the sample that marks the start): nothing moved
        if sample.timestamp < self.time:
            self._warn(f"odometry at {sample.timestamp!r} s is before the filter's {self.time!r} s (time going backwards): skipped")
            return
        due = sorted((p for p in self._pending if p.timestamp <= sample.timestamp), key=lambda p: (p.timestamp, p.order))
        self._pending = [p for p in self._pending if p.timestamp > sample.timestamp]
        for pending in due:
            self._predict(pending.timestamp - self.time, speed, rate)
            self.time = pending.timestamp
            self._update(pending.record)
        self._predict(sample.timestamp - self.time, speed, rate)
        self.time = float(sample.timestamp)

    def _predict(self, dt: float, speed: float, rate: float) -> None:
        if dt <= 0:
            return
        n = len(self.x)
        scale, bias = self.x[SCALE], self.x[BIAS]
        change, d_yaw, d_inputs = unicycle_step(self.x[YAW], scale * speed * dt, (rate - bias) * dt)
        self.x[[X, Y, YAW]] += change
        F = np.eye(n)
        F[[X, Y, YAW], YAW] += d_yaw
        F[[X, Y, YAW], SCALE] += d_inputs[:, 0] * speed * dt
        F[[X, Y, YAW], BIAS] -= d_inputs[:, 1] * dt
        G = np.zeros((n, 2))  # d(state)/d(speed, yaw rate)
        G[[X, Y, YAW]] = d_inputs * [scale * dt, dt]
        speed_sigma = self.noise.speed_sigma_fraction * abs(speed) + self.noise.speed_sigma_m_s
        Q = G @ np.diag([speed_sigma**2, self.noise.yaw_rate_sigma_rad_s**2]) @ G.T
        Q[SCALE, SCALE] += self.noise.scale_walk_per_sqrt_s**2 * dt
        Q[BIAS, BIAS] += self.noise.yaw_rate_bias_walk_rad_s_per_sqrt_s**2 * dt
        walk = self.noise.range_bias_walk_m_per_sqrt_s**2 * dt
        Q[range(BASE_STATES, n), range(BASE_STATES, n)] += walk
        self.P = F @ self.P @ F.T + Q

    # ---- updates -------------------------------------------------------------------------------

    def _update(self, record: BeaconRange | GpsFix) -> None:
        n = len(self.x)
        if isinstance(record, BeaconRange):
            index = self.beacon_ids.index(record.beacon_id)
            bx, by, bz = self.beacons[record.beacon_id]
            dx, dy, dz = self.x[X] - bx, self.x[Y] - by, self.antenna_height_m - bz
            distance = max(math.sqrt(dx * dx + dy * dy + dz * dz), 1e-6)
            gain = 1.0 + self.x[RANGE_SCALE]
            H = np.zeros((1, n))
            H[0, X], H[0, Y] = gain * dx / distance, gain * dy / distance
            H[0, RANGE_SCALE], H[0, BASE_STATES + index] = distance, 1.0
            residual = np.array([record.range_m - gain * distance - self.x[BASE_STATES + index]])
            R = np.array([[self.noise.range_sigma_m**2]])
            source = f"range:{record.beacon_id}"
        else:
            east, north, _ = self.gnss_frame.to_enu(record.latitude_deg, record.longitude_deg, record.altitude_m)[0]
            H = np.zeros((2, n))
            H[0, X] = H[1, Y] = 1.0
            residual = np.array([east - self.x[X], north - self.x[Y]])
            sigma = (
                record.horizontal_accuracy_m if math.isfinite(record.horizontal_accuracy_m) and record.horizontal_accuracy_m > 0 else self.noise.gnss_sigma_m
            )
            R = np.eye(2) * sigma**2
            source = "gnss"
        innovation, S_inv = gated_innovation(float(record.timestamp), source, residual, H @ self.P @ H.T + R, self.noise.gate_probability)
        self.innovations.append(innovation)
        if not innovation.accepted:
            return
        K = self.P @ H.T @ S_inv
        self.x += K @ residual
        I_KH = np.eye(n) - K @ H
        self.P = I_KH @ self.P @ I_KH.T + K @ R @ K.T  # Joseph form: stays symmetric positive

    def _warn(self, text: str) -> None:
        """Each kind of problem once in ``warnings`` (a long run of bad samples is one line)."""
        kind = text.split(":")[0] if ":" in text else text
        if kind not in self._warned:
            self._warned.add(kind)
            self.warnings.append(text)


def multilaterate(
    beacons: dict[str, tuple[float, float, float]], ranges: list[BeaconRange], height_m: float = 0.0, estimate_bias: bool = False
) -> tuple[np.ndarray, np.ndarray, float]:
    """Position (x, y), its 2x2 covariance (unit range noise: scale by the range variance) and a
    range bias common to all beacons (0 unless ``estimate_bias``) from ranges taken at one place,
    by Gauss-Newton least squares started at the beacons' centroid.

    Needs ranges to at least 2 beacons (3 to fix the mirror image, one more with the bias)."""
    used = [r for r in ranges if r.beacon_id in beacons and math.isfinite(r.range_m)]
    distinct = {r.beacon_id for r in used}
    needed = 4 if estimate_bias else 3
    if len(distinct) < needed:
        raise ValueError(f"ranges to {len(distinct)} distinct beacons; {needed} are needed to multilaterate")
    anchors = np.array([beacons[r.beacon_id] for r in used], dtype=float)
    measured = np.array([r.range_m for r in used])
    estimate = np.array([*anchors[:, :2].mean(axis=0), 0.0])
    columns = 3 if estimate_bias else 2
    for _ in range(20):
        delta = np.column_stack([estimate[0] - anchors[:, 0], estimate[1] - anchors[:, 1], height_m - anchors[:, 2]])
        distance = np.maximum(np.linalg.norm(delta, axis=1), 1e-6)
        J = np.column_stack([delta[:, 0] / distance, delta[:, 1] / distance, np.ones(len(used))])[:, :columns]
        step = np.linalg.lstsq(J, measured - distance - estimate[2], rcond=None)[0]
        estimate[:columns] += step
        if np.linalg.norm(step) < 1e-6:
            break
    covariance = np.linalg.inv(J.T @ J)[:2, :2]
    return estimate[:2].copy(), covariance, float(estimate[2])
