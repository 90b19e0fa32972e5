"""Wheel odometry from a robot's raw encoder counters: the ticks between two readings, made
speeds by the ticks' length, with the counters' wrap and their jumps handled explicitly.

A counter of ``counter_bits`` bits wraps from its largest value to 0 (or back, driving in
reverse): the difference of two readings modulo ``2^bits``, taken in ``[-2^(bits-1), 2^(bits-1))``,
is the true tick count as long as a wheel turns less than half the counter's range between two
readings (a 16-bit counter of 360 ticks per turn of a 3.5 cm wheel: 11 m, while a robot at 2 m/s
covers 4 cm per 20 ms sample). A difference that still means a speed beyond ``max_speed_m_s``
is a jump (a reset microcontroller, a glitch on the line), not motion: that sample's speeds are
NaN, which the EKF-SLAM replaces by the last good input with its noise inflated, and a warning
says so. A change in the number of counters, or a reading not after the last, restarts the
differences (warning) rather than inventing motion.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from evp.config import RobotSettings
from evp.types import EncoderCounts, WheelOdometry


def tick_difference(new: int, old: int, counter_bits: int) -> int:
    """``new - old`` of a counter that wraps at ``2^counter_bits``, in ``[-2^(bits-1), 2^(bits-1))``."""
    span = 1 << counter_bits
    return (new - old + span // 2) % span - span // 2


@dataclass
class EncoderOdometry:
    """Feed :meth:`sample` each :class:`EncoderCounts` in time order; it returns the wheel record
    for the interval since the previous one (None for the first, which starts the differences)."""

    robot: RobotSettings
    warnings: list[str] = field(default_factory=list)
    _last: EncoderCounts | None = None

    def sample(self, reading: EncoderCounts) -> WheelOdometry | None:
        last, self._last = self._last, reading
        if last is None:
            return None
        if len(reading.counts) != len(last.counts):
            self.warnings.append(f"encoder reading at {reading.timestamp:.3f} s has {len(reading.counts)} counters, the last had {len(last.counts)}: restarted")
            return None
        dt = reading.timestamp - last.timestamp
        if not dt > 0:
            self.warnings.append(f"encoder reading at {reading.timestamp!r} s is not after the last ({last.timestamp!r} s): restarted from it")
            return None
        r = self.robot
        speeds = [tick_difference(new, old, r.counter_bits) * r.metres_per_tick / dt for new, old in zip(reading.counts, last.counts)]
        if any(abs(v) > r.max_wheel_speed_m_s for v in speeds):
            text = ", ".join(f"{v:.1f}" for v in speeds)
            self.warnings.append(
                f"encoder jump at {reading.timestamp:.3f} s: wheel speeds {text} m/s beyond {r.max_wheel_speed_m_s:g} m/s: not motion, sample left out"
            )
            speeds = [math.nan] * len(speeds)
        forward = sum(speeds) / len(speeds) if speeds else math.nan
        yaw_rate = reading.yaw_rate_rad_s
        if not math.isfinite(yaw_rate) and len(speeds) == 2:  # no gyro: the differential drive's own turn rate
            yaw_rate = (speeds[1] - speeds[0]) / r.wheel_base_m
        return WheelOdometry(reading.timestamp, tuple(speeds), forward, yaw_rate)
