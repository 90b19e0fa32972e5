"""A simulated drone for station tests: seed 003's quadrotor over the marker floor with a phone
looking down, streaming its frames and sonar to a station as a phone on a drone does
(``evp.mobile.client.StreamClient``), and flown by the station's marker autopilot over MAVLink:
its flight controller (``evp.sim.flight_controller``) says armed in GUIDED and holds the
velocity set-points that come back."""

from __future__ import annotations

import math
import threading
from collections.abc import Iterator

import numpy as np

from evp.mobile.sources import StreamSource
from evp.sim.flight_controller import VelocityHold
from evp.sim.mission import PHYSICS_STEPS_PER_FRAME, MissionRun, MissionSpec
from evp.types import Frame, RangeSample

ARDUCOPTER_GUIDED = 4


class SimulatedDrone:
    def __init__(self, mavlink_url: str, seed: int = 1, start_marker: int = 49, fps: float = 15.0, resolution=(240, 180), max_s: float = 60.0):
        from pymavlink import mavutil

        self.run = MissionRun(MissionSpec(seed=seed, start_marker=start_marker, fps=fps, resolution=resolution, duration_s=max_s))
        self.controller = VelocityHold()
        self.mavlink = mavutil.mavlink_connection(mavlink_url, source_system=1, source_component=1, dialect="common")
        self.fps = fps
        self.max_s = max_s
        self.stop = threading.Event()
        self.setpoints = 0
        self._next_heartbeat = 0.0

    def source(self) -> StreamSource:
        return StreamSource("simulated drone", self.run.renderer.camera, self.fps, self._items(), live=False, lossless=True, skipped=[])

    @property
    def position(self) -> np.ndarray:
        return self.run.vehicle.state.position.copy()

    def _items(self) -> Iterator:
        dt = 1.0 / self.fps
        index = 0
        while not self.stop.is_set() and self.run.t < self.max_s:
            t = self.run.t
            self._mavlink(t)
            image, reading = self.run.sense()
            if math.isfinite(reading):
                yield RangeSample(t, reading)
            yield Frame(t, image, index=index, source="simulated drone")
            index += 1
            for k in range(PHYSICS_STEPS_PER_FRAME):
                tilt, climb = self.controller.command(t + k * dt / PHYSICS_STEPS_PER_FRAME, self.run.vehicle.state, dt / PHYSICS_STEPS_PER_FRAME)
                self.run.vehicle.step(tilt, climb, True, dt / PHYSICS_STEPS_PER_FRAME)
            self.run.t = round(t + dt, 9)

    def _mavlink(self, t: float) -> None:
        """The controller's side: its heartbeat (armed, GUIDED) each second, the set-points in."""
        from pymavlink.dialects.v20 import common as mavlink

        if t >= self._next_heartbeat:
            base = mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | mavlink.MAV_MODE_FLAG_SAFETY_ARMED
            self.mavlink.mav.heartbeat_send(mavlink.MAV_TYPE_QUADROTOR, mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA, base, ARDUCOPTER_GUIDED, mavlink.MAV_STATE_ACTIVE)
            self._next_heartbeat = t + 1.0
        while (message := self.mavlink.recv_match(type="SET_POSITION_TARGET_LOCAL_NED", blocking=False)) is not None:
            self.controller.setpoint(t, message.vx, message.vy, message.vz)
            self.setpoints += 1

    def close(self) -> None:
        self.mavlink.close()
