"""The pose to a flight controller: MAVLink ODOMETRY and VISION_POSITION_ESTIMATE (PX4, ArduPilot).

Frames: the SLAM world is the first camera frame. With the vehicle level at the start and the
camera on it as ``mount`` says, the local NED frame is the body frame at that moment (heading 0
is the take-off heading, not north), and the body is FRD:

    T_ned_body(t) = T_body_cam . T_world_cam(t) . T_body_cam^-1

Messages go out at a fixed rate: the newest camera pose, carried forward at its last velocity
for at most ``max_extrapolation_s`` when the next one is late; nothing while tracking is lost,
so the autopilot's own timeout takes over. ``reset_counter`` counts relocalisations and new maps.
"""

from __future__ import annotations

import math
import os
import threading
import time
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from evp.config import MavlinkSettings
from evp.geometry.transforms import quat_xyzw_from_matrices, se3_inverse
from evp.types import TrackingState

os.environ.setdefault("MAVLINK20", "1")  # quality and reset_counter are MAVLink 2 extensions

# Columns: camera x (right), y (down in the image), z (optical axis) expressed in body FRD.
MOUNTS = {
    "down": np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]),  # image top towards the nose
    "forward": np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]),
}


def mount_transform(settings: MavlinkSettings) -> np.ndarray:
    """T_body_cam: the preset mount turned by the extra roll/pitch/yaw (degrees, body axes)."""
    T = np.eye(4)
    extra = Rotation.from_euler("xyz", settings.mount_rpy_deg, degrees=True).as_matrix()
    T[:3, :3] = extra @ MOUNTS[settings.mount]
    T[:3, 3] = settings.mount_offset_m
    return T


def body_pose_ned(T_world_cam: np.ndarray, T_body_cam: np.ndarray) -> np.ndarray:
    return T_body_cam @ T_world_cam @ se3_inverse(T_body_cam)


def euler_frd(R: np.ndarray) -> tuple[float, float, float]:
    """Roll, pitch, yaw (ZYX aerospace convention) of a body-to-NED rotation."""
    pitch = -math.asin(max(-1.0, min(1.0, R[2, 0])))
    return math.atan2(R[2, 1], R[2, 2]), pitch, math.atan2(R[1, 0], R[0, 0])


def quat_wxyz(R: np.ndarray) -> list[float]:
    x, y, z, w = quat_xyzw_from_matrices(R[None])[0]
    return [float(w), float(x), float(y), float(z)]


@dataclass
class BodyState:
    """One camera pose in the autopilot's frames, with velocities from the previous pose."""

    time_s: float  # on the mobile station's clock
    received_at: float  # station wall clock
    T_ned_body: np.ndarray
    velocity_body: np.ndarray  # m/s in FRD (NaN when unknown)
    rates_body: np.ndarray  # rad/s about FRD axes (NaN when unknown)
    quality: int
    reset_counter: int


def next_state(previous: BodyState | None, T_ned_body: np.ndarray, time_s: float, received_at: float, quality: int, reset_counter: int) -> BodyState:
    velocity = np.full(3, np.nan)
    rates = np.full(3, np.nan)
    if previous is not None and previous.reset_counter == reset_counter and time_s > previous.time_s:
        dt = time_s - previous.time_s
        R = T_ned_body[:3, :3]
        velocity = R.T @ (T_ned_body[:3, 3] - previous.T_ned_body[:3, 3]) / dt
        rates = Rotation.from_matrix(previous.T_ned_body[:3, :3].T @ R).as_rotvec() / dt
    return BodyState(time_s, received_at, T_ned_body, velocity, rates, quality, reset_counter)


def extrapolate(state: BodyState, now: float) -> tuple[float, np.ndarray]:
    """(mobile time, T_ned_body) carried forward at the last velocity to station time ``now``."""
    dt = max(0.0, now - state.received_at)
    T = state.T_ned_body.copy()
    if dt > 0 and np.all(np.isfinite(state.velocity_body)):
        T[:3, 3] += T[:3, :3] @ state.velocity_body * dt
        T[:3, :3] = T[:3, :3] @ Rotation.from_rotvec(state.rates_body * dt).as_matrix()
    return state.time_s + dt, T


# The flight controller's estimator rejects samples whose time goes backwards. Extrapolating the
# newest pose can do that by a frame when poses arrive with jitter; a larger step back is a new
# mobile clock (a new session), which restarts the sequence.
BACKWARDS_RESET_USEC = 1_000_000


class MavlinkOutput:
    """Sends the newest pose at ``settings.rate_hz`` on a pymavlink connection (UDP or serial)."""

    def __init__(self, url: str, settings: MavlinkSettings):
        from pymavlink import mavutil

        self.url = url
        self.settings = settings
        self.T_body_cam = mount_transform(settings)
        self.connection = mavutil.mavlink_connection(url, source_system=settings.system_id, source_component=settings.component_id, dialect="common")
        self.mavlink = self.connection.mav
        self._state: BodyState | None = None
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self.sent = 0
        self._last_usec = -1
        self._thread = threading.Thread(target=self._loop, name="evp-mavlink", daemon=True)
        self._thread.start()

    def update(self, T_world_cam: np.ndarray, time_s: float, state: str, quality: int, reset_counter: int) -> None:
        """A new camera pose; a lost one stops the stream until tracking is back."""
        now = time.monotonic()
        with self._lock:
            if not TrackingState(state).tracked:
                self._state = None
                return
            T = body_pose_ned(T_world_cam, self.T_body_cam)
            self._state = next_state(self._state, T, time_s, now, quality, reset_counter % 256)

    def _loop(self) -> None:
        from pymavlink.dialects.v20 import common as mavlink

        period = 1.0 / self.settings.rate_hz
        next_heartbeat = 0.0
        deadline = time.monotonic()
        while not self._stop.is_set():
            now = time.monotonic()
            if now >= next_heartbeat:
                self.mavlink.heartbeat_send(mavlink.MAV_TYPE_ONBOARD_CONTROLLER, mavlink.MAV_AUTOPILOT_INVALID, 0, 0, mavlink.MAV_STATE_ACTIVE)
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
        covariance = [math.nan] + [0.0] * 20  # unknown (MAVLink: NaN in the first element)
        frame = mavlink.MAV_FRAME_LOCAL_NED if self.settings.frame == "local_ned" else mavlink.MAV_FRAME_LOCAL_FRD
        v = [float(a) for a in state.velocity_body]
        w = [float(a) for a in state.rates_body]
        self.mavlink.odometry_send(
            usec, frame, mavlink.MAV_FRAME_BODY_FRD, x, y, z, quat_wxyz(T[:3, :3]), *v, *w, covariance, covariance,
            reset_counter=state.reset_counter, estimator_type=mavlink.MAV_ESTIMATOR_TYPE_VISION, quality=state.quality,
        )  # fmt: skip
        roll, pitch, yaw = euler_frd(T[:3, :3])
        self.mavlink.vision_position_estimate_send(usec, x, y, z, roll, pitch, yaw, covariance, reset_counter=state.reset_counter)
        self.sent += 1

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=2)
        self.connection.close()
