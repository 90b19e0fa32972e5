"""Speed of the navigation filter (``evp.fusion.navigation_filter``) on one core: the cost of one
IMU propagation and of one update per measurement kind, on a 20 s synthetic flight (200 Hz IMU,
20 Hz visual poses, 5 Hz GPS, 10 Hz barometer), and of a GPS fix that arrives 0.2 s late (a
roll-back and 40 re-propagated IMU samples). Targets (issue 30): <= 0.5 ms per IMU sample, <= 2 ms
per visual update.

Usage: python bench/navigation_filter_speed.py

Needs no data. Prints one row per operation: its mean and 95th-percentile time in microseconds.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np
from results import Results

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the tests' closed-form trajectory

from evp.config import NavigationSettings  # noqa: E402
from evp.fusion.measurements import BaroAltitude  # noqa: E402
from evp.fusion.navigation_filter import NavigationFilter  # noqa: E402
from tests.fusion.inertial_trajectory import SinusoidTrajectory  # noqa: E402
from tests.fusion.test_navigation_filter import gps_fix, noisy_imu, visual_pose  # noqa: E402

COLUMNS = [("operation", "{operation}"), ("calls", "{calls}"), ("mean (us)", "{mean_us:.0f}"), ("p95 (us)", "{p95_us:.0f}"), ("target (us)", "{target_us}")]
TARGETS = {"propagate (one IMU sample)": 500, "update: visual pose": 2000}


def measure() -> dict[str, list[float]]:
    settings = NavigationSettings(initial_yaw_sigma_rad=0.05, initial_log_scale_sigma=0.3)
    trajectory = SinusoidTrajectory()
    rng = np.random.default_rng(0)
    nav = NavigationFilter(trajectory.state(0.0, log_scale=np.log(3.5)), settings)
    times: dict[str, list[float]] = {}

    def timed(name, call, *args):
        start = time.perf_counter()
        result = call(*args)
        times.setdefault(name, []).append(time.perf_counter() - start)
        return result

    late = None
    for k, sample in enumerate(noisy_imu(trajectory, 20.0, settings)):
        timed("propagate (one IMU sample)", nav.propagate, sample)
        t = sample.timestamp
        if k % 10 == 0:
            timed("update: visual pose", nav.update, visual_pose(trajectory, t, rng))
        if k % 20 == 5:
            timed("update: barometer", nav.update, BaroAltitude(t, trajectory.position(t)[2] + 0.3 * rng.standard_normal(), 0.3))
        if k % 40 == 0 and k > 0:
            if k % 200 == 0:
                late = gps_fix(trajectory, t, rng)
            else:
                timed("update: GPS", nav.update, gps_fix(trajectory, t, rng))
        if late is not None and t >= late.timestamp + 0.2:
            timed("update: GPS 0.2 s late (roll-back)", nav.update, late)
            late = None
    return times


def main() -> None:
    results = Results("navigation_filter_speed", "python bench/navigation_filter_speed.py")
    table = results.table("speed", COLUMNS, key=["operation"], caption="One core; the machine's load shows in the p95.")
    print(table.header())
    for operation, seconds in measure().items():
        us = np.asarray(seconds) * 1e6
        record = {
            "operation": operation,
            "calls": len(us),
            "mean_us": float(us.mean()),
            "p95_us": float(np.percentile(us, 95)),
            "target_us": TARGETS.get(operation, "-"),
        }
        print(table.add(record))


if __name__ == "__main__":
    main()
