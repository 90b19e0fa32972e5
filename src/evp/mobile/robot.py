"""The wheel robot's end of the link (or its simulator's): the velocity the station commands,
held only while commands keep coming, and the encoder counters the robot sends.

The watchdog is the robot's own safety, not the station's: the station repeats its command every
``robot.command_interval_s`` while it drives, so a link that drops (Wi-Fi or Bluetooth out of
range, the station stopped) is, seen from the robot, commands that stop coming. After
``robot.watchdog_timeout_s`` without one the robot stops: zero velocity, whatever was commanded
last, until a new command comes. Time is passed in (the robot's control loop polls
:meth:`VelocityWatchdog.velocity` at its own rate), so the behaviour is tested exactly.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Iterator
from dataclasses import dataclass

from evp.config import RobotSettings
from evp.station.protocol import Velocity
from evp.types import EncoderCounts, WheelOdometry


@dataclass
class VelocityWatchdog:
    """The commanded velocity, zero once ``timeout_s`` passed without a command; ``stops``
    counts the times the watchdog (not a command) stopped the robot."""

    timeout_s: float
    linear_m_s: float = 0.0
    angular_rad_s: float = 0.0
    stops: int = 0
    _heard_at: float = -math.inf

    def command(self, message: Velocity, now: float) -> None:
        self.linear_m_s, self.angular_rad_s, self._heard_at = message.linear_m_s, message.angular_rad_s, now

    def velocity(self, now: float) -> tuple[float, float]:
        """``(linear m/s, angular rad/s)`` to drive at ``now``."""
        if now - self._heard_at > self.timeout_s and (self.linear_m_s or self.angular_rad_s):
            self.linear_m_s = self.angular_rad_s = 0.0
            self.stops += 1
        return self.linear_m_s, self.angular_rad_s


def encoder_readings(wheel: Iterable[WheelOdometry], robot: RobotSettings) -> Iterator[EncoderCounts]:
    """What a robot's encoders would have sent for these wheel records (each wheel's speed held
    over the interval since the previous record): whole ticks counted from 0, the fraction
    carried over, the counters wrapping at ``robot.counter_bits``, the gyro's rate passed on.
    The robot simulator of ``evp stream --encoder-ticks``."""
    span = 1 << robot.counter_bits
    travelled: list[float] | None = None
    previous = None
    for record in wheel:
        if travelled is None:
            travelled = [0.0] * len(record.wheel_speeds_m_s)
        elif len(record.wheel_speeds_m_s) == len(travelled):
            dt = record.timestamp - previous
            travelled = [d + v * dt for d, v in zip(travelled, record.wheel_speeds_m_s)]
        previous = record.timestamp
        counts = tuple(math.floor(d / robot.metres_per_tick + 0.5) % span for d in travelled)
        yield EncoderCounts(record.timestamp, counts, record.yaw_rate_rad_s)
