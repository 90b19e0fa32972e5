"""A wheel robot on a session's link, at the station: its encoder readings made wheel odometry
for the estimator (:mod:`evp.fusion.wheel_encoders`), and the velocity command the station
drives it with, repeated every ``robot.command_interval_s`` so that the robot's watchdog
(:mod:`evp.mobile.robot`) hears one well inside its timeout while the link lives.

No socket and no clock here: the session passes the time in and sends what comes out.
"""

from __future__ import annotations

import math

from evp.config import RobotSettings
from evp.fusion.wheel_encoders import EncoderOdometry
from evp.station.protocol import Velocity
from evp.types import EncoderCounts, WheelOdometry


class RobotLink:
    def __init__(self, robot: RobotSettings):
        self.robot = robot
        self.encoders = EncoderOdometry(robot)
        self.command: Velocity | None = None  # the command being repeated (None: not driving)
        self._sent_at = -math.inf

    def wheel_record(self, reading: EncoderCounts) -> tuple[WheelOdometry | None, list[str]]:
        """The wheel record for ``reading`` (None for the first) and the warnings it raised."""
        told = len(self.encoders.warnings)
        record = self.encoders.sample(reading)
        return record, self.encoders.warnings[told:]

    def drive(self, linear_m_s: float, angular_rad_s: float, now: float) -> Velocity:
        """The command to send now, clamped to the robot's limits; repeated from then on. A zero
        command is sent once and not repeated (the robot's watchdog keeps it stopped)."""
        if not (math.isfinite(linear_m_s) and math.isfinite(angular_rad_s)):
            raise ValueError(f"velocity command ({linear_m_s!r} m/s, {angular_rad_s!r} rad/s) is not finite")
        r = self.robot
        command = Velocity(
            linear_m_s=max(-r.max_linear_m_s, min(r.max_linear_m_s, linear_m_s)),
            angular_rad_s=max(-r.max_angular_rad_s, min(r.max_angular_rad_s, angular_rad_s)),
        )
        moving = command.linear_m_s != 0 or command.angular_rad_s != 0
        self.command, self._sent_at = (command if moving else None), now
        return command

    def link_lost(self) -> None:
        """The link dropped: the command is not repeated after a reconnect (the robot's watchdog
        has stopped it; it moves again only on a new command)."""
        self.command = None

    def due(self, now: float) -> Velocity | None:
        """The current command again when ``command_interval_s`` has passed since it was last sent."""
        if self.command is None or now - self._sent_at < self.robot.command_interval_s:
            return None
        self._sent_at = now
        return self.command
