"""The pose to a flight controller: one MAVLink ODOMETRY stream per vehicle, as its autopilot wants it.

Profiles (``mavlink.profile``), one message type each, so that no pose is fused twice:

- ``ardupilot``: ODOMETRY with ``frame_id`` MAV_FRAME_LOCAL_FRD and ``child_frame_id``
  MAV_FRAME_BODY_FRD, always (the only pair ArduPilot's external-navigation handler takes; with
  ``VISO_TYPE`` 3 it aligns the frame's heading itself);
- ``px4``: ODOMETRY with ``frame_id`` MAV_FRAME_LOCAL_NED once the heading is known (the answer is
  georeferenced: its world is ENU), else MAV_FRAME_LOCAL_FRD (arbitrary heading); child
  MAV_FRAME_BODY_FRD.

Frames. A metric answer (the navigation filter's) is in a z-up world: ENU once georeferenced, the
levelled visual map otherwise; the body is FRD with the camera mounted as ``mount`` says:

    T_ned_body = T_NED_ENU . T_world_cam . T_body_cam^-1

An answer in the visual map's units (no IMU) keeps the earlier convention: the local frame is the
body at the start (heading 0 = take-off heading), ``T_ned_body = T_body_cam . T_world_cam .
T_body_cam^-1``, no covariance (NaN: unknown).

Messages go out at ``rate_hz``: the newest pose carried forward at its velocity for at most
``max_extrapolation_s``; nothing while there is no usable pose (tracking lost without a filter,
or the filter's quality 0), so the autopilot's own timeout takes over. ``reset_counter`` comes from
the answers (every jump of their frame). ``statustext`` relays the GPS alarms; with ``gps_input``
the georeferenced position also goes out as GPS_INPUT (for an autopilot configured for a MAVLink
GPS), only while the answers are georeferenced. Each vehicle's session gets its own output (its
endpoint or its system id: ``evp.station.base_station``).
"""

from __future__ import annotations

import math
import os
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from evp.config import MavlinkSettings
from evp.geometry.transforms import quat_xyzw_from_matrices, se3_inverse
from evp.station.estimation import pose_matrix
from evp.station.protocol import Pose
from evp.types import TrackingState

os.environ.setdefault("MAVLINK20", "1")  # quality and reset_counter are MAVLink 2 extensions

# Columns: camera x (right), y (down in the image), z (optical axis) expressed in body FRD.
MOUNTS = {
    "down": np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]),  # image top towards the nose
    "forward": np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]),
}
R_NED_ENU = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
T_NED_ENU = np.eye(4)
T_NED_ENU[:3, :3] = R_NED_ENU
GPS_INPUT_PERIOD_S = 0.2  # 5 Hz: ArduPilot's MAVLink GPS driver expects at least that
# GPS_INPUT's satellite count: EVP has none, but the autopilots' GPS checks refuse a fix with fewer
# than 6 (ArduPilot's arming check) or 6-10 (PX4's EKF2_REQ_NSATS default 6); 10 passes both.
SATELLITES_REPORTED = 10
GPS_WEEK_S = 7 * 86400.0
GPS_EPOCH_UNIX_S = 315964800.0  # 1980-01-06
GPS_LEAP_SECONDS = 18  # GPS time minus UTC since 2017 (IERS Bulletin C)


def mount_transform(settings: MavlinkSettings) -> np.ndarray:
    """T_body_cam: the preset mount turned by the extra roll/pitch/yaw (degrees, body axes)."""
    T = np.eye(4)
    extra = Rotation.from_euler("xyz", settings.mount_rpy_deg, degrees=True).as_matrix()
    T[:3, :3] = extra @ MOUNTS[settings.mount]
    T[:3, 3] = settings.mount_offset_m
    return T


def body_pose_ned(T_world_cam: np.ndarray, T_body_cam: np.ndarray) -> np.ndarray:
    """The body in the local frame of a visual map answer (the body at the start)."""
    return T_body_cam @ T_world_cam @ se3_inverse(T_body_cam)


def body_pose_from_metric(T_world_cam: np.ndarray, T_body_cam: np.ndarray) -> np.ndarray:
    """The FRD body in NED (or a z-down frame of arbitrary heading) from a z-up metric answer."""
    return T_NED_ENU @ T_world_cam @ se3_inverse(T_body_cam)


def euler_frd(R: np.ndarray) -> tuple[float, float, float]:
    """Roll, pitch, yaw (ZYX aerospace convention) of a body-to-NED rotation."""
    pitch = -math.asin(max(-1.0, min(1.0, R[2, 0])))
    return math.atan2(R[2, 1], R[2, 2]), pitch, math.atan2(R[1, 0], R[0, 0])


def quat_wxyz(R: np.ndarray) -> list[float]:
    x, y, z, w = quat_xyzw_from_matrices(R[None])[0]
    return [float(w), float(x), float(y), float(z)]


def upper_triangle(C: np.ndarray) -> list[float]:
    """MAVLink's covariance layout: the upper-right triangle, row-major (21 numbers for 6x6)."""
    n = C.shape[0]
    return [float(C[i, j]) for i in range(n) for j in range(i, n)]


UNKNOWN_COVARIANCE = [math.nan] + [0.0] * 20  # MAVLink: NaN in the first element


def pose_covariance_ned(covariance: list[float]) -> list[float]:
    """A wire covariance (6x6 over world position and world rotation vector, z up) in NED axes,
    as MAVLink's 21 numbers; roll, pitch, yaw taken as the rotation about north, east, down (the
    small-angle reading the autopilots make of it)."""
    C = np.asarray(covariance, float).reshape(6, 6)
    J = np.zeros((6, 6))
    J[:3, :3] = J[3:, 3:] = R_NED_ENU
    return upper_triangle(J @ C @ J.T)


@dataclass(frozen=True)
class AutopilotProfile:
    """How one autopilot family wants the pose: ``frame_id`` for a pose whose heading is known
    (north-aligned) or not."""

    name: str
    frame_heading_known: int
    frame_heading_unknown: int
    child_frame: int

    def frame_id(self, heading_known: bool) -> int:
        return self.frame_heading_known if heading_known else self.frame_heading_unknown


def profile(name: str) -> AutopilotProfile:
    from pymavlink.dialects.v20 import common as mavlink

    if name == "ardupilot":  # AP_VisualOdom takes LOCAL_FRD / BODY_FRD only
        return AutopilotProfile(name, mavlink.MAV_FRAME_LOCAL_FRD, mavlink.MAV_FRAME_LOCAL_FRD, mavlink.MAV_FRAME_BODY_FRD)
    return AutopilotProfile(name, mavlink.MAV_FRAME_LOCAL_NED, mavlink.MAV_FRAME_LOCAL_FRD, mavlink.MAV_FRAME_BODY_FRD)


@dataclass
class BodyState:
    """One answer in the autopilot's frames."""

    time_s: float  # on the mobile station's clock
    received_at: float  # station monotonic clock
    T_ned_body: np.ndarray
    velocity_body: np.ndarray  # m/s in FRD (NaN when unknown)
    rates_body: np.ndarray  # rad/s about FRD axes (NaN when unknown)
    quality: int
    reset_counter: int
    heading_known: bool = False
    pose_covariance: list[float] | None = None  # MAVLink's 21, NED
    velocity_covariance: list[float] | None = None  # MAVLink's 21 (velocity block only), body FRD
    geodetic: tuple[float, float, float] | None = None  # latitude, longitude, altitude while georeferenced
    velocity_ned: np.ndarray | None = None
    horizontal_sigma_m: float = math.nan
    vertical_sigma_m: float = math.nan


def state_from_pose(pose: Pose, previous: BodyState | None, T_body_cam: np.ndarray, received_at: float, reset_counter: int) -> BodyState:
    """The wire answer in the autopilot's frames; velocities from the filter when metric, else
    from the previous answer (same reset counter), else unknown."""
    T_world_cam = pose_matrix(pose)
    T = body_pose_from_metric(T_world_cam, T_body_cam) if pose.metric else body_pose_ned(T_world_cam, T_body_cam)
    R = T[:3, :3]
    velocity, rates = np.full(3, np.nan), np.full(3, np.nan)
    velocity_ned = None
    if previous is not None and previous.reset_counter == reset_counter and pose.timestamp > previous.time_s:
        dt = pose.timestamp - previous.time_s
        velocity = R.T @ (T[:3, 3] - previous.T_ned_body[:3, 3]) / dt
        rates = Rotation.from_matrix(previous.T_ned_body[:3, :3].T @ R).as_rotvec() / dt
    state = BodyState(pose.timestamp, received_at, T, velocity, rates, pose.quality, reset_counter % 256, heading_known=pose.metric and pose.georeferenced)
    if pose.metric and pose.velocity is not None:
        velocity_ned = R_NED_ENU @ np.asarray(pose.velocity)
        state.velocity_body, state.velocity_ned = R.T @ velocity_ned, velocity_ned
    if pose.metric and pose.covariance is not None:
        state.pose_covariance = pose_covariance_ned(pose.covariance)
        C = np.asarray(pose.covariance).reshape(6, 6)
        state.horizontal_sigma_m = math.sqrt(max(0.0, 0.5 * (C[0, 0] + C[1, 1])))
        state.vertical_sigma_m = math.sqrt(max(0.0, C[2, 2]))
    if pose.metric and pose.velocity_covariance is not None:
        Rv = R.T @ R_NED_ENU  # world (ENU) to body FRD
        V = Rv @ np.asarray(pose.velocity_covariance).reshape(3, 3) @ Rv.T
        full = np.zeros((6, 6))
        full[:3, :3] = V
        full[3:, 3:] = np.diag([math.nan] * 3)  # rates' variance: unknown
        state.velocity_covariance = upper_triangle(full)
    if pose.latitude_deg is not None and pose.longitude_deg is not None and pose.altitude_m is not None:
        state.geodetic = (pose.latitude_deg, pose.longitude_deg, pose.altitude_m)
    return state


def usable(pose: Pose) -> bool:
    """A pose the autopilot may fly on: vision tracking, or the filter with some confidence left."""
    return (pose.metric and pose.quality > 0) or TrackingState(pose.state).tracked


def extrapolate(state: BodyState, now: float) -> tuple[float, np.ndarray]:
    """(mobile time, T_ned_body) carried forward at the last velocity to station time ``now``."""
    dt = max(0.0, now - state.received_at)
    T = state.T_ned_body.copy()
    if dt > 0 and np.all(np.isfinite(state.velocity_body)):
        T[:3, 3] += T[:3, :3] @ state.velocity_body * dt
        if np.all(np.isfinite(state.rates_body)):
            T[:3, :3] = T[:3, :3] @ Rotation.from_rotvec(state.rates_body * dt).as_matrix()
    return state.time_s + dt, T


def gps_time(unix_s: float) -> tuple[int, int]:
    """(GPS week, milliseconds into it) of a UNIX time."""
    gps_s = unix_s - GPS_EPOCH_UNIX_S + GPS_LEAP_SECONDS
    week = int(gps_s // GPS_WEEK_S)
    return week, int(round((gps_s - week * GPS_WEEK_S) * 1000.0))


# The flight controller's estimator rejects samples whose time goes backwards. Extrapolating the
# newest pose can do that by a frame when poses arrive with jitter; a larger step back is a new
# mobile clock (a new session), which restarts the sequence.
BACKWARDS_RESET_USEC = 1_000_000


class MavlinkOutput:
    """Sends the newest pose at ``settings.rate_hz`` on a pymavlink connection (UDP, TCP, serial),
    as ``settings.profile`` wants it. ``on_problem(text)`` hears of an endpoint that refuses
    (once per outage; called from the output's thread)."""

    def __init__(self, url: str, settings: MavlinkSettings, system_id: int | None = None, on_problem: Callable[[str], None] = lambda text: None):
        from pymavlink import mavutil

        self.url = url
        self.settings = settings
        self.profile = profile(settings.profile)
        self.T_body_cam = mount_transform(settings)
        self.system_id = system_id or settings.system_id
        self.connection = mavutil.mavlink_connection(url, source_system=self.system_id, source_component=settings.component_id, dialect="common")
        self.mavlink = self.connection.mav
        self._on_problem = on_problem
        self._failing = False
        self._state: BodyState | None = None
        self._lock = threading.Lock()
        self.send_lock = threading.Lock()  # the marker autopilot's set-points share this connection (evp.station.marker_mission)
        self._stop = threading.Event()
        self.sent = 0
        self._last_usec = -1
        self._last_gps_input = -math.inf
        self._thread = threading.Thread(target=self._loop, name="evp-mavlink", daemon=True)
        self._thread.start()

    def update(self, pose: Pose, reset_counter: int) -> None:
        """A new answer; one the autopilot cannot fly on stops the stream until one it can."""
        now = time.monotonic()
        with self._lock:
            if not usable(pose):
                self._state = None
                return
            self._state = state_from_pose(pose, self._state, self.T_body_cam, now, reset_counter)

    def statustext(self, severity: int, text: str) -> None:
        """A message for the pilot's ground station (GPS alarms); MAVLink carries 50 characters."""
        self._guarded(lambda: self.mavlink.statustext_send(severity, text.encode()[:50]))

    def _guarded(self, send: Callable[[], None]) -> bool:
        try:
            with self.send_lock:
                send()
        except OSError as exc:
            if not self._failing:
                self._failing = True
                self._on_problem(f"MAVLink endpoint {self.url} refuses: {exc}")
            return False
        self._failing = False
        return True

    def _loop(self) -> None:
        from pymavlink.dialects.v20 import common as mavlink

        period = 1.0 / self.settings.rate_hz
        next_heartbeat = 0.0
        deadline = time.monotonic()
        while not self._stop.is_set():
            now = time.monotonic()
            if now >= next_heartbeat:
                self._guarded(
                    lambda: self.mavlink.heartbeat_send(mavlink.MAV_TYPE_ONBOARD_CONTROLLER, mavlink.MAV_AUTOPILOT_INVALID, 0, 0, mavlink.MAV_STATE_ACTIVE)
                )
                next_heartbeat = now + 1.0
            with self._lock:
                state = self._state
            if state is not None and now - state.received_at <= self.settings.max_extrapolation_s:
                self._send(state, now, mavlink)
            deadline += period
            self._stop.wait(max(0.0, deadline - time.monotonic()))

    def _send(self, state: BodyState, now: float, mavlink) -> None:
        time_s, T = extrapolate(state, now)
        usec = int(round(time_s * 1e6))
        if 0 <= self._last_usec - usec < BACKWARDS_RESET_USEC:
            return  # a pose that arrived late extrapolates to before the last one sent: skip the tick
        self._last_usec = usec
        x, y, z = (float(v) for v in T[:3, 3])
        v = [float(a) for a in state.velocity_body]
        w = [float(a) for a in state.rates_body]
        frame = self.profile.frame_id(state.heading_known)
        sent = self._guarded(
            lambda: self.mavlink.odometry_send(
                usec,
                frame,
                self.profile.child_frame,
                x,
                y,
                z,
                quat_wxyz(T[:3, :3]),
                *v,
                *w,
                state.pose_covariance or UNKNOWN_COVARIANCE,
                state.velocity_covariance or UNKNOWN_COVARIANCE,
                reset_counter=state.reset_counter,
                estimator_type=mavlink.MAV_ESTIMATOR_TYPE_VIO,
                quality=state.quality,
            )  # fmt: skip
        )
        self.sent += sent
        if self.settings.gps_input and state.geodetic is not None and now - self._last_gps_input >= GPS_INPUT_PERIOD_S:
            self._last_gps_input = now
            self._send_gps_input(state, mavlink)

    def _send_gps_input(self, state: BodyState, mavlink) -> None:
        """The georeferenced position as a GPS (3-D fix); accuracies from the filter's covariance.
        The altitude is the WGS-84 ellipsoid height of the take-off fix's frame (GPS_INPUT asks for
        MSL: the geoid offset, tens of metres, is the same at every fix, as with a phone's GPS)."""
        lat, lon, alt = state.geodetic
        week, week_ms = gps_time(time.time())
        vn, ve, vd = (float(a) for a in (state.velocity_ned if state.velocity_ned is not None else np.zeros(3)))
        ignore = mavlink.GPS_INPUT_IGNORE_FLAG_HDOP | mavlink.GPS_INPUT_IGNORE_FLAG_VDOP | mavlink.GPS_INPUT_IGNORE_FLAG_SPEED_ACCURACY
        self._guarded(
            lambda: self.mavlink.gps_input_send(
                int(state.time_s * 1e6),
                0,
                ignore,
                week_ms,
                week,
                3,
                int(round(lat * 1e7)),
                int(round(lon * 1e7)),
                float(alt),
                1.0,
                1.0,
                vn,
                ve,
                vd,
                0.0,
                float(state.horizontal_sigma_m),
                float(state.vertical_sigma_m),
                SATELLITES_REPORTED,
            )  # fmt: skip
        )

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=2)
        self.connection.close()
