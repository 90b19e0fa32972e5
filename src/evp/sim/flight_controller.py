"""A flight controller in GUIDED mode for the simulated quadrotor: it holds the velocity set-points
a companion computer sends (SET_POSITION_TARGET_LOCAL_NED in MAV_FRAME_BODY_NED: forward, right,
down), as ArduCopter's GUIDED velocity control does, so the station's marker autopilot can fly the
simulated vehicle over MAVLink exactly as it would fly a real one.

The controller's own velocity estimate is the simulated truth (a real controller's EKF); a
proportional-integral loop turns the velocity error into tilt (the integral takes up the wind and
the trim error), the climb set-point goes straight to the climb rate. A set-point older than
``timeout_s`` is replaced by zero velocity, as ArduCopter stops when GUIDED set-points stop (3 s).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from evp.sim.quadrotor import QuadrotorState

GUIDED_TIMEOUT_S = 3.0  # ArduCopter: GUIDED velocity commands older than this stop the vehicle


@dataclass
class VelocityHold:
    gain: float = 0.3  # tilt (rad) per m/s of velocity error
    integral_gain: float = 0.4  # tilt per m/s per second
    max_tilt_rad: float = 0.25
    max_integral_rad: float = 0.08
    timeout_s: float = GUIDED_TIMEOUT_S
    _setpoint: np.ndarray = field(default_factory=lambda: np.zeros(3))  # forward, right, down (m/s)
    _received_s: float = -math.inf
    _integral: np.ndarray = field(default_factory=lambda: np.zeros(2))

    def setpoint(self, time_s: float, forward: float, right: float, down: float) -> None:
        self._setpoint = np.array([forward, right, down], float)
        self._received_s = time_s

    def command(self, time_s: float, state: QuadrotorState, dt: float) -> tuple[np.ndarray, float]:
        """(tilt forward/left in rad, climb rate in m/s) for the quadrotor's next ``dt``."""
        wanted = self._setpoint if time_s - self._received_s <= self.timeout_s else np.zeros(3)
        forward = np.array([math.cos(state.yaw), math.sin(state.yaw)])
        left = np.array([-math.sin(state.yaw), math.cos(state.yaw)])
        velocity = np.array([state.velocity[:2] @ forward, state.velocity[:2] @ left])
        error = np.array([wanted[0], -wanted[1]]) - velocity
        self._integral = np.clip(self._integral + self.integral_gain * error * dt, -self.max_integral_rad, self.max_integral_rad)
        tilt = np.clip(self.gain * error + self._integral, -self.max_tilt_rad, self.max_tilt_rad)
        return tilt, float(-wanted[2])
