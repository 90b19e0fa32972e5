"""A small quadrotor for closed-loop flights: attitude-controlled, with thrust and tilt limits,
linear drag, seeded wind gusts and the drifts seed 003 describes.

The flight controller (seed 003's microcontroller) holds the commanded tilt through a first-order
lag and the climb rate through thrust; nothing holds position, so a trim error (a level that is not
quite level: IMU aberrations, unequal weight) and the wind make it drift unless the autopilot
corrects. Near the floor the rotors' own air swashes add gusts (seed 003, 3.2.5). The body frame is
x forward, y left, z up; the camera and the sonar sit at the body origin, ``landing_gear_m`` above
the floor when landed.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from pydantic import BaseModel, ConfigDict, Field
from scipy.spatial.transform import Rotation

GRAVITY_M_S2 = 9.80665


class QuadrotorConfig(BaseModel):
    model_config = ConfigDict(extra="forbid")

    attitude_time_constant_s: float = Field(0.08, gt=0, description="tilt follows its command with this lag")
    max_tilt_rad: float = Field(0.35, gt=0, description="the flight controller's tilt limit (20 deg)")
    max_thrust_g: float = Field(1.68, gt=1, description="thrust over weight: seed 003's 1410 g of thrust for 840 g")
    climb_time_constant_s: float = Field(0.2, gt=0)
    drag_per_s: float = Field(0.4, ge=0, description="linear drag: horizontal deceleration per m/s of air speed")
    wind_m_s: float = Field(
        0.2,
        ge=0,
        description="mean wind (random direction per seed): with the trim error it takes an uncorrected hover off seed 003's map in about 7 s, as the paper saw",
    )
    gust_sigma_m_s: float = Field(0.08, ge=0, description="gusts: Ornstein-Uhlenbeck wind variation, 1 sigma")
    gust_time_s: float = Field(1.5, gt=0, description="gust correlation time")
    swash_height_m: float = Field(0.3, gt=0, description="air swashes: gusts grow by up to 1.5x below about this height")
    trim_error_rad: float = Field(0.004, ge=0, description="level error of the attitude controller, 1 sigma per axis (random per seed)")
    yaw_drift_rad_s: float = Field(0.01, ge=0, description="heading random walk, rad/sqrt(s)")
    landing_gear_m: float = Field(0.08, gt=0, description="camera and sonar above the floor when landed")


@dataclass
class QuadrotorState:
    position: np.ndarray  # (3,) world, body origin
    velocity: np.ndarray
    tilt: np.ndarray  # (2,) forward (nose down), left, rad
    yaw: float

    def rotation(self) -> np.ndarray:
        """Body to world: yaw, then pitch nose-down about y, then roll towards the left about -x."""
        return Rotation.from_euler("ZYX", [self.yaw, self.tilt[0], -self.tilt[1]]).as_matrix()


class Quadrotor:
    """Integrates the vehicle at ``dt`` under (tilt, climb rate, motors) commands."""

    def __init__(self, config: QuadrotorConfig, rng: np.random.Generator, start_xy: np.ndarray, yaw: float = math.pi / 2):
        self.config = config
        self.rng = rng
        self.state = QuadrotorState(np.array([start_xy[0], start_xy[1], config.landing_gear_m]), np.zeros(3), np.zeros(2), yaw)
        heading = rng.uniform(0, 2 * math.pi)
        self.wind_mean = config.wind_m_s * np.array([math.cos(heading), math.sin(heading)])
        self.wind = self.wind_mean.copy()
        self.trim_error = rng.normal(0, config.trim_error_rad, 2)

    def step(self, tilt_command: np.ndarray, climb_command: float, motors: bool, dt: float) -> None:
        c = self.config
        s = self.state
        airborne = s.position[2] > c.landing_gear_m + 1e-4
        command = np.clip(tilt_command, -c.max_tilt_rad, c.max_tilt_rad) if motors else np.zeros(2)
        s.tilt = s.tilt + (command - s.tilt) * min(1.0, dt / c.attitude_time_constant_s)
        swash = 1.0 + 0.5 * math.exp(-(s.position[2] - c.landing_gear_m) / c.swash_height_m)
        decay = dt / c.gust_time_s
        self.wind = self.wind + (self.wind_mean - self.wind) * decay + self.rng.normal(0, c.gust_sigma_m_s * swash * math.sqrt(2 * decay), 2)
        if not airborne and (not motors or climb_command <= 0):
            s.velocity[:] = 0.0
            s.tilt[:] = 0.0
            return
        actual = s.tilt + (self.trim_error if motors else 0.0)
        forward = np.array([math.cos(s.yaw), math.sin(s.yaw)])
        left = np.array([-math.sin(s.yaw), math.cos(s.yaw)])
        horizontal = GRAVITY_M_S2 * (math.tan(actual[0]) * forward + math.tan(actual[1]) * left) + c.drag_per_s * (self.wind - s.velocity[:2])
        if motors:
            vertical = (climb_command - s.velocity[2]) / c.climb_time_constant_s
            vertical = float(np.clip(vertical, -GRAVITY_M_S2, (c.max_thrust_g - 1.0) * GRAVITY_M_S2))
        else:
            vertical = -GRAVITY_M_S2
        s.velocity = s.velocity + np.array([horizontal[0], horizontal[1], vertical]) * dt
        s.position = s.position + s.velocity * dt
        s.yaw += self.rng.normal(0, c.yaw_drift_rad_s * math.sqrt(dt))
        if s.position[2] < c.landing_gear_m:
            s.position[2] = c.landing_gear_m
            s.velocity[:] = 0.0
