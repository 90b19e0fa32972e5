"""Measurement models of the navigation filter: for each sensor, a record of what it measured and
its linearisation at a nominal state: residual (measured minus predicted), Jacobian ``H`` with
respect to the error state (layout in :mod:`evp.fusion.nav_state`) and noise covariance ``R``.

A reading that cannot be used (NaN, out of the sensor's range, a range finder tilted off the
ground) linearises to a :class:`Refusal` naming why, never to a residual. Noise sigmas left NaN
take the :class:`~evp.config.NavigationSettings` default. Jacobians use ``R = R_nominal Exp(dtheta)``
for the body attitude and ``R_world_map = Exp(dtheta_map) R_nominal`` for the visual map.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from evp.config import NavigationSettings
from evp.fusion.nav_state import (
    ATTITUDE,
    BARO_BIAS,
    ERROR_DIM,
    GPS_BIAS,
    GYRO_BIAS,
    LOG_SCALE,
    MAP_ATTITUDE,
    MAP_POSITION,
    POSITION,
    VELOCITY,
    NavState,
    skew3,
    so3_log,
)


@dataclass(frozen=True)
class Linearisation:
    residual: np.ndarray  # (m,) measured minus predicted
    jacobian: np.ndarray  # (m, ERROR_DIM)
    noise: np.ndarray  # (m, m)


@dataclass(frozen=True)
class Refusal:
    """Why a reading was not used (before any gate)."""

    reason: str


def _sigma(value: float, default: float) -> float:
    return value if math.isfinite(value) and value > 0 else default


def _finite(*values) -> bool:
    return all(np.all(np.isfinite(np.asarray(v, float))) for v in values)


@dataclass(frozen=True)
class VisualPose:
    """A SLAM/VO camera pose in its own map (arbitrary frame and scale): ``T_map_cam`` 4x4;
    ``T_body_cam`` is the camera-IMU extrinsic (camera in the IMU frame, metres); ``depth`` the
    median depth of the scene it was tracked on, in map units (NaN: not known).

    Its position noise is the larger of ``visual_position_sigma_m`` and
    ``visual_position_sigma_per_depth`` times that depth: a pose fixed on points d away moves with
    their errors, which grow with d (a pixel is d / f wide there, and triangulated depths are
    worse), so one sigma in metres fits a camera 1 m above a floor or 100 m above a field, never both."""

    timestamp: float
    T_map_cam: np.ndarray
    T_body_cam: np.ndarray
    depth: float = float("nan")
    kind = "visual"

    def linearise(self, x: NavState, gyro: np.ndarray, s: NavigationSettings) -> Linearisation | Refusal:
        if not _finite(self.T_map_cam):
            return Refusal("visual pose is not finite")
        R_bc, t_bc = self.T_body_cam[:3, :3], self.T_body_cam[:3, 3]
        scale = x.scale
        R_mw = x.R_world_map.T
        d = x.position + x.R_world_body @ t_bc - x.t_world_map  # camera relative to the map origin, world, m
        predicted_position = R_mw @ d / scale
        R_map_cam = R_mw @ x.R_world_body @ R_bc
        H = np.zeros((6, ERROR_DIM))
        H[0:3, POSITION] = R_mw / scale
        H[0:3, ATTITUDE] = -R_mw @ x.R_world_body @ skew3(t_bc) / scale
        H[0:3, LOG_SCALE] = -predicted_position
        H[0:3, MAP_ATTITUDE] = R_mw @ skew3(d) / scale
        H[0:3, MAP_POSITION] = -R_mw / scale
        H[3:6, ATTITUDE] = R_bc.T
        H[3:6, MAP_ATTITUDE] = -R_bc.T @ x.R_world_body.T
        residual = np.concatenate([self.T_map_cam[:3, 3] - predicted_position, so3_log(R_map_cam.T @ self.T_map_cam[:3, :3])])
        position_sigma = s.visual_position_sigma_m / scale
        if math.isfinite(self.depth):
            position_sigma = max(position_sigma, s.visual_position_sigma_per_depth * self.depth)
        noise = np.diag(np.repeat([position_sigma**2, s.visual_attitude_sigma_rad**2], 3))
        return Linearisation(residual, H, noise)


@dataclass(frozen=True)
class RefinedScale:
    """The visual map's scale (metres per map unit) with its relative 1-sigma, estimated apart
    from the filter: the inertial refinement over the keyframes kept since the map began
    (:mod:`evp.fusion.scale_refinement`)."""

    timestamp: float
    scale: float
    sigma: float
    T_body_cam: np.ndarray = field(default_factory=lambda: np.eye(4))  # the camera in the IMU frame
    kind = "refined_scale"

    def linearise(self, x: NavState, gyro: np.ndarray, s: NavigationSettings) -> Linearisation | Refusal:
        if not (_finite(self.scale, self.sigma) and self.scale > 0 and self.sigma > 0):
            return Refusal(f"refined scale {self.scale} +- {self.sigma} is not a positive finite number")
        if not x.map_anchored:
            return Refusal("the visual map is not anchored: no scale to measure")
        H = np.zeros((1, ERROR_DIM))
        H[0, LOG_SCALE] = 1.0
        return Linearisation(np.array([math.log(self.scale) - x.log_scale]), H, np.array([[self.sigma**2]]))

    def carried(self, x: NavState) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The states that move with the scale by geometry, not by the filter's correlations:
        with the body kept where the map has it, the camera's offset from the map's origin and the
        velocity (both seen through the map) grow with the scale, and the body's attitude and the
        map's pose stay. Returns the states, their change for this step (by ``exp(r) - 1`` for a
        change ``r`` of the log scale: exact, not first order) and their change per unit of the log
        scale at the new one (for its uncertainty)."""
        change = math.log(self.scale) - x.log_scale
        growth = math.expm1(change) / change if abs(change) > 1e-12 else 1.0
        offset = x.position + x.R_world_body @ self.T_body_cam[:3, 3] - x.t_world_map
        states = np.r_[LOG_SCALE, POSITION, VELOCITY, ATTITUDE, MAP_ATTITUDE, MAP_POSITION]
        kept = np.zeros(9)
        step = np.r_[1.0, growth * offset, growth * x.velocity, kept][:, None]
        sensitivity = np.r_[1.0, math.exp(change) * offset, math.exp(change) * x.velocity, kept][:, None]
        return states, step, sensitivity


@dataclass(frozen=True)
class BaroAltitude:
    """Barometric altitude (m); the filter's bias state absorbs its offset from world z."""

    timestamp: float
    altitude_m: float
    sigma_m: float = float("nan")
    kind = "baro"

    def linearise(self, x: NavState, gyro: np.ndarray, s: NavigationSettings) -> Linearisation | Refusal:
        if not _finite(self.altitude_m):
            return Refusal("barometer altitude is not finite")
        H = np.zeros((1, ERROR_DIM))
        H[0, 2] = 1.0
        H[0, BARO_BIAS] = 1.0
        residual = np.array([self.altitude_m - (x.position[2] + x.baro_bias)])
        return Linearisation(residual, H, np.array([[_sigma(self.sigma_m, s.baro_sigma_m) ** 2]]))


@dataclass(frozen=True)
class RangeHeight:
    """A range finder's distance (m) along ``axis_body`` (a unit vector in the IMU frame, default
    straight down the body's -z) from ``offset_body``, to flat ground at world height
    ``ground_height_m``."""

    timestamp: float
    distance_m: float
    ground_height_m: float = 0.0
    axis_body: tuple[float, float, float] = (0.0, 0.0, -1.0)
    offset_body: tuple[float, float, float] = (0.0, 0.0, 0.0)
    sigma_m: float = float("nan")
    kind = "range"

    def linearise(self, x: NavState, gyro: np.ndarray, s: NavigationSettings) -> Linearisation | Refusal:
        if not _finite(self.distance_m) or self.distance_m <= 0:
            return Refusal("range finder reading is not a positive finite distance (out of range)")
        axis = np.asarray(self.axis_body, float)
        offset = np.asarray(self.offset_body, float)
        down = -(x.R_world_body @ axis)[2]  # cosine of the beam's tilt from straight down
        if down < math.cos(s.range_max_tilt_rad):
            return Refusal(f"range finder tilted {math.degrees(math.acos(min(1.0, max(-1.0, down)))):.0f} deg from the vertical")
        height = x.position[2] + (x.R_world_body @ offset)[2] - self.ground_height_m
        H = np.zeros((1, ERROR_DIM))
        H[0, 2] = 1.0 / down
        d_height = -(x.R_world_body @ skew3(offset))[2]
        d_down = (x.R_world_body @ skew3(axis))[2]
        H[0, ATTITUDE] = d_height / down - height * d_down / down**2
        residual = np.array([self.distance_m - height / down])
        return Linearisation(residual, H, np.array([[_sigma(self.sigma_m, s.range_sigma_m) ** 2]]))


@dataclass(frozen=True)
class GpsPosition:
    """A GPS fix already in the world frame (ENU at the take-off point, metres), with its 1-sigma
    accuracies and, when the receiver gives it, its ENU velocity; ``antenna_body`` is the antenna
    in the IMU frame. The fix is the antenna's position plus the filter's GPS error state (the
    correlated part of the fix's error, see :mod:`evp.fusion.nav_state`) plus white noise: only
    ``gps_white_share`` of the accuracy's variance is new in each fix."""

    timestamp: float
    position_enu: tuple[float, float, float]
    horizontal_sigma_m: float = float("nan")
    vertical_sigma_m: float = float("nan")
    velocity_enu: tuple[float, float, float] | None = None
    velocity_sigma_m_s: float = float("nan")
    antenna_body: tuple[float, float, float] = (0.0, 0.0, 0.0)
    kind = "gps"

    def variances(self, s: NavigationSettings) -> np.ndarray:
        """The fix's error variance per ENU axis (white and correlated parts together): the
        horizontal accuracy is both axes' RMS (:class:`evp.types.GpsFix`), half its square each."""
        horizontal = _sigma(self.horizontal_sigma_m, s.gps_default_sigma_m)
        vertical = _sigma(self.vertical_sigma_m, 1.5 * horizontal)  # GPS vertical is ~1.5x worse (typical receiver specs)
        return np.array([horizontal**2 / 2, horizontal**2 / 2, vertical**2])

    def linearise(self, x: NavState, gyro: np.ndarray, s: NavigationSettings) -> Linearisation | Refusal:
        if not _finite(self.position_enu):
            return Refusal("GPS position is not finite (no lock)")
        antenna = np.asarray(self.antenna_body, float)
        rows = [np.asarray(self.position_enu, float) - (x.position + x.R_world_body @ antenna + x.gps_bias)]
        variances = list(s.gps_white_share * self.variances(s))
        H = np.zeros((3, ERROR_DIM))
        H[:, POSITION] = np.eye(3)
        H[:, ATTITUDE] = -x.R_world_body @ skew3(antenna)
        H[:, GPS_BIAS] = np.eye(3)
        if self.velocity_enu is not None and _finite(self.velocity_enu):
            rows.append(np.asarray(self.velocity_enu, float) - x.velocity)
            variances += [_sigma(self.velocity_sigma_m_s, s.gps_velocity_sigma_m_s) ** 2] * 3
            Hv = np.zeros((3, ERROR_DIM))
            Hv[:, VELOCITY] = np.eye(3)
            H = np.vstack([H, Hv])
        return Linearisation(np.concatenate(rows), H, np.diag(variances))


@dataclass(frozen=True)
class WheelSpeed:
    """A ground vehicle's forward speed from its wheels (NaN: none, the constraint alone) and the
    non-holonomic constraint: no lateral and no vertical speed in the vehicle frame (x forward,
    ``R_body_vehicle`` its axes in the IMU frame). The lever arm from the IMU to the rear axle is
    neglected (its ``w x r`` term is small at the yaw rates of a car)."""

    timestamp: float
    forward_speed_m_s: float = float("nan")
    R_body_vehicle: np.ndarray = field(default_factory=lambda: np.eye(3))
    kind = "wheels"

    def linearise(self, x: NavState, gyro: np.ndarray, s: NavigationSettings) -> Linearisation | Refusal:
        R_vw = self.R_body_vehicle.T @ x.R_world_body.T
        velocity_body = x.R_world_body.T @ x.velocity
        H = np.zeros((3, ERROR_DIM))
        H[:, VELOCITY] = R_vw
        H[:, ATTITUDE] = self.R_body_vehicle.T @ skew3(velocity_body)
        predicted = R_vw @ x.velocity
        residual = np.array([self.forward_speed_m_s, 0.0, 0.0]) - predicted
        sigmas = np.array([s.wheel_speed_sigma_m_s, s.non_holonomic_sigma_m_s, s.non_holonomic_sigma_m_s])
        rows = slice(0, 3) if math.isfinite(self.forward_speed_m_s) else slice(1, 3)
        return Linearisation(residual[rows], H[rows], np.diag(sigmas[rows] ** 2))


@dataclass(frozen=True)
class YawRate:
    """A ground vehicle's yaw rate (rad/s, about the vehicle's up axis) from a wheel odometer or
    a separate gyro: it constrains the IMU's gyro bias through the latest gyro reading."""

    timestamp: float
    yaw_rate_rad_s: float
    R_body_vehicle: np.ndarray = field(default_factory=lambda: np.eye(3))
    sigma_rad_s: float = float("nan")
    kind = "yaw_rate"

    def linearise(self, x: NavState, gyro: np.ndarray, s: NavigationSettings) -> Linearisation | Refusal:
        if not _finite(self.yaw_rate_rad_s):
            return Refusal("yaw rate is not finite")
        up = self.R_body_vehicle[:, 2]  # vehicle up axis in the IMU frame
        H = np.zeros((1, ERROR_DIM))
        H[0, GYRO_BIAS] = -up
        residual = np.array([self.yaw_rate_rad_s - up @ (gyro - x.gyro_bias)])
        return Linearisation(residual, H, np.array([[_sigma(self.sigma_rad_s, s.yaw_rate_sigma_rad_s) ** 2]]))


@dataclass(frozen=True)
class BeaconDistance:
    """Range (m) from the tag at ``tag_body`` (IMU frame) to a fixed beacon at a known world
    position, minus a known ``bias_m`` (e.g. UWB antenna delay, estimated beforehand)."""

    timestamp: float
    beacon_position: tuple[float, float, float]
    range_m: float
    bias_m: float = 0.0
    tag_body: tuple[float, float, float] = (0.0, 0.0, 0.0)
    sigma_m: float = float("nan")
    kind = "beacon"

    def linearise(self, x: NavState, gyro: np.ndarray, s: NavigationSettings) -> Linearisation | Refusal:
        if not _finite(self.range_m, self.beacon_position, self.bias_m):
            return Refusal("beacon range or position is not finite")
        tag = np.asarray(self.tag_body, float)
        offset = x.position + x.R_world_body @ tag - np.asarray(self.beacon_position, float)
        distance = float(np.linalg.norm(offset))
        if distance < 1e-6:
            return Refusal("tag is at the beacon: the range's direction is undefined")
        u = offset / distance
        H = np.zeros((1, ERROR_DIM))
        H[0, POSITION] = u
        H[0, ATTITUDE] = -u @ x.R_world_body @ skew3(tag)
        residual = np.array([self.range_m - self.bias_m - distance])
        return Linearisation(residual, H, np.array([[_sigma(self.sigma_m, s.beacon_range_sigma_m) ** 2]]))


@dataclass(frozen=True)
class MarkerPose:
    """The camera's pose from one marker whose world pose is known: an absolute, metric fix of
    position and attitude (heading included), with neither the visual map's scale nor its gauge.
    ``T_world_marker`` is the marker in the world (a surveyed marker, or one of a marker map whose
    frame is the world's: evp.markers.marker_map's x, y, theta on a floor at z = 0, z up);
    ``R_cam_marker``, ``t_cam_marker`` the pose solved from its corners
    (:class:`evp.markers.detection.MarkerObservation`); ``T_body_cam`` the camera-IMU extrinsic.
    A second marker with a mapped id is an innovation far outside the gate: refused there."""

    timestamp: float
    T_world_marker: np.ndarray
    R_cam_marker: np.ndarray
    t_cam_marker: np.ndarray
    T_body_cam: np.ndarray
    position_sigma_m: float = float("nan")
    attitude_sigma_rad: float = float("nan")
    kind = "marker"

    def linearise(self, x: NavState, gyro: np.ndarray, s: NavigationSettings) -> Linearisation | Refusal:
        if not _finite(self.T_world_marker, self.R_cam_marker, self.t_cam_marker):
            return Refusal("marker pose is not finite")
        R_wm, t_wm = self.T_world_marker[:3, :3], self.T_world_marker[:3, 3]
        R_world_cam = R_wm @ self.R_cam_marker.T
        t_world_cam = t_wm - R_world_cam @ self.t_cam_marker
        R_bc, t_bc = self.T_body_cam[:3, :3], self.T_body_cam[:3, 3]
        H = np.zeros((6, ERROR_DIM))
        H[0:3, POSITION] = np.eye(3)
        H[0:3, ATTITUDE] = -x.R_world_body @ skew3(t_bc)
        H[3:6, ATTITUDE] = R_bc.T
        predicted_rotation = x.R_world_body @ R_bc
        residual = np.concatenate([t_world_cam - (x.position + x.R_world_body @ t_bc), so3_log(predicted_rotation.T @ R_world_cam)])
        sigmas = (_sigma(self.position_sigma_m, s.marker_position_sigma_m), _sigma(self.attitude_sigma_rad, s.marker_attitude_sigma_rad))
        return Linearisation(residual, H, np.diag(np.repeat(np.square(sigmas), 3)))


Measurement = VisualPose | BaroAltitude | RangeHeight | GpsPosition | WheelSpeed | YawRate | BeaconDistance | MarkerPose
