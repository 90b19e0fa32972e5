"""The seed 003 autopilot driving a real flight controller over MAVLink (ArduPilot GUIDED, PX4
OFFBOARD): velocity set-points, a mode and arming check, a watchdog, and the pilot's override.

The autopilot's command goes out as SET_POSITION_TARGET_LOCAL_NED with only the velocity set
(MAV_FRAME_BODY_NED: forward, right, down, so the map's heading never has to be aligned with the
controller's north); the controller holds that velocity with its own estimator. Set-points are
sent only while the controller's HEARTBEAT says armed and in GUIDED (ArduCopter custom mode 4) or
OFFBOARD (PX4 main mode 6). When the pilot switches to any other mode (the RC transmitter's mode
switch), the pilot wins at once: no further set-point is sent until the mode is given back, and
that is logged. ``tick`` is the watchdog, called by the runtime between frames: when frames stop
it steps the autopilot without a frame, which holds (zero velocity) and lands after
``land_after_s``. No thread and no clock of its own: the caller drives it and injects the clock.
Without a connection (a vehicle with no MAVLink endpoint yet) the autopilot still runs, so the
operator sees the map and the state, and nothing is sent. The set-points go to the system that
sends the controller's heartbeats; ``lock`` serialises sends on a connection another thread also
writes (the station's ODOMETRY output shares the vehicle's link).
"""

from __future__ import annotations

import contextlib
import math
import time
from collections.abc import Callable

import numpy as np

from evp.autopilot.pilot import Autopilot, Command
from evp.markers.detection import MarkerObservation

ARDUCOPTER_GUIDED = 4
PX4_OFFBOARD = 6
# position, acceleration, yaw and yaw rate ignored: velocity only (POSITION_TARGET_TYPEMASK)
VELOCITY_ONLY = 0b0000_1101_1100_0111
HEARTBEAT_PERIOD_S = 1.0


class MavlinkAutopilotLink:
    """One autopilot, one flight controller. ``connection`` is a pymavlink connection (or None)."""

    def __init__(
        self,
        connection,
        autopilot: Autopilot,
        clock: Callable[[], float] = time.monotonic,
        target_system: int = 1,
        target_component: int = 1,
        lock: contextlib.AbstractContextManager | None = None,
    ):
        self.connection = connection
        self.lock = lock or contextlib.nullcontext()
        self.autopilot = autopilot
        self.clock = clock
        self.target = (target_system, target_component)
        self.armed = False
        self.in_control = False  # armed and in GUIDED/OFFBOARD: our set-points fly the vehicle
        self.mode = "unknown"
        self.sent = 0
        self._frame_clock: float | None = None
        self._frame_time: float = 0.0
        self._range = float("nan")
        self._next_heartbeat = -math.inf
        self._refused_logged = False

    # --- from the flight controller ----------------------------------------------------------------
    def poll(self) -> None:
        """Read every pending message; a HEARTBEAT from the controller updates arming and mode."""
        from pymavlink.dialects.v20 import common as mavlink

        if self.connection is None:
            return
        while (message := self.connection.recv_match(blocking=False)) is not None:
            if message.get_type() != "HEARTBEAT" or message.type in (mavlink.MAV_TYPE_GCS, mavlink.MAV_TYPE_ONBOARD_CONTROLLER):
                continue
            self._on_heartbeat(message, mavlink)

    def _on_heartbeat(self, message, mavlink) -> None:
        self.target = (message.get_srcSystem(), message.get_srcComponent())
        self.armed = bool(message.base_mode & mavlink.MAV_MODE_FLAG_SAFETY_ARMED)
        if message.autopilot == mavlink.MAV_AUTOPILOT_PX4:
            guided = (message.custom_mode >> 16) & 0xFF == PX4_OFFBOARD
        else:
            guided = message.custom_mode == ARDUCOPTER_GUIDED
        self.mode = "guided" if guided else f"custom {message.custom_mode}"
        control = self.armed and guided
        if self.in_control and not control:
            self.autopilot.log(
                "manual_override", f"the controller left GUIDED/OFFBOARD or disarmed (mode {self.mode}, armed {self.armed}): the pilot wins, no set-points"
            )
        elif control and not self.in_control:
            self.autopilot.log("in_control", "armed and in GUIDED/OFFBOARD: velocity set-points on")
            self._refused_logged = False
        self.in_control = control

    # --- from the camera and the watchdog ----------------------------------------------------------
    def on_frame(self, time_s: float, observations: list[MarkerObservation], range_m: float) -> Command:
        self.poll()
        self._frame_clock, self._frame_time, self._range = self.clock(), time_s, range_m
        command = self.autopilot.step(time_s, observations, range_m)
        self._send(command)
        return command

    def tick(self, range_m: float | None = None) -> Command | None:
        """Between frames: heartbeat, messages, and when the frames have stopped for longer than
        the autopilot's ``frame_timeout_s``, a step without a frame (hold, later land)."""
        now = self.clock()
        self.poll()
        if now >= self._next_heartbeat and self.connection is not None:
            from pymavlink.dialects.v20 import common as mavlink

            with self.lock:
                self.connection.mav.heartbeat_send(mavlink.MAV_TYPE_ONBOARD_CONTROLLER, mavlink.MAV_AUTOPILOT_INVALID, 0, 0, mavlink.MAV_STATE_ACTIVE)
            self._next_heartbeat = now + HEARTBEAT_PERIOD_S
        if range_m is not None:
            self._range = range_m
        if self._frame_clock is None or now - self._frame_clock <= self.autopilot.settings.frame_timeout_s:
            return None
        command = self.autopilot.step(self._frame_time + (now - self._frame_clock), None, self._range)
        self._send(command)
        return command

    def _send(self, command: Command) -> None:
        if not self.in_control:
            if not self._refused_logged:
                why = (
                    "no MAVLink endpoint for this vehicle"
                    if self.connection is None
                    else f"not armed in GUIDED/OFFBOARD (armed {self.armed}, mode {self.mode})"
                )
                self.autopilot.log("no_setpoint", f"{why}: set-points withheld")
                self._refused_logged = True
            return
        yaw = math.pi / 2 if self.autopilot.position is None else float(self.autopilot.position[2])
        forward = np.array([math.cos(yaw), math.sin(yaw)])
        right = np.array([math.sin(yaw), -math.cos(yaw)])
        velocity = command.velocity_map if command.motors else np.zeros(2)
        climb = command.climb_m_s if command.motors else 0.0
        with self.lock:
            self.connection.mav.set_position_target_local_ned_send(
                int(self.clock() * 1000) & 0xFFFFFFFF, *self.target, 8, VELOCITY_ONLY,  # 8: MAV_FRAME_BODY_NED
                0.0, 0.0, 0.0, float(velocity @ forward), float(velocity @ right), float(-climb), 0.0, 0.0, 0.0, 0.0, 0.0,
            )  # fmt: skip
        self.sent += 1
