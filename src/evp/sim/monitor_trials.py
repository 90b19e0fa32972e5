"""Seeded trials of the GPS consistency monitor on simulated flights (no images needed): used by
the tests, bench/gps_alignment.py and the seed002-spoofing experiment (experiments on the
simulator, so not part of the core).

The visual track is the truth replayed with a scale and a heading error of ``drift_fraction``
(1 sigma each, slowly wandering), so its error grows in proportion to the distance travelled like a
visual odometry's after alignment; GPS comes from the simulator's GPS model (Gauss-Markov + white
noise, spoofing, outages).
"""

from __future__ import annotations

import numpy as np

from evp.config import MonitorSettings
from evp.fusion.geodesy import EnuFrame
from evp.fusion.gps_monitor import GpsMonitor
from evp.sim import sensors
from evp.sim.scenarios import SimOptions, build_scenario

ALIGNED_AFTER_S = 70.0


def drifting_track(truth: np.ndarray, drift_fraction: float, rng: np.random.Generator) -> np.ndarray:
    """``truth`` (N, 2 or 3) re-integrated with scale and heading errors of ~``drift_fraction``
    (1 sigma), wandering slowly (a random walk reaching that size over the track)."""
    steps = np.diff(truth, axis=0, prepend=truth[:1])
    n = len(truth)
    wander = np.cumsum(rng.normal(0, 1, (n, 2)), axis=0) / np.sqrt(n)
    scale = 1.0 + drift_fraction * (rng.normal() + wander[:, 0])
    heading = drift_fraction * (rng.normal() + wander[:, 1])
    cos, sin = np.cos(heading), np.sin(heading)
    moved = steps.copy()
    moved[:, 0] = scale * (cos * steps[:, 0] - sin * steps[:, 1])
    moved[:, 1] = scale * (sin * steps[:, 0] + cos * steps[:, 1])
    if truth.shape[1] > 2:
        moved[:, 2] = scale * steps[:, 2]
    return truth[0] + np.cumsum(moved, axis=0)


def monitor_run(
    gps_config: sensors.GpsConfig, seed: int, duration_s: float = 300.0, drift_fraction: float = 0.005, errors: list[tuple[float, float]] | None = None
) -> GpsMonitor:
    """The monitor over one seeded flight; ``errors`` (when given) receives (time, horizontal error
    of the monitored position, the visual track plus the monitor's correction, against the truth)
    at each fix after the alignment phase."""
    scenario = build_scenario("drone-flight", SimOptions(duration_s=duration_s, relief=False, seed=seed))
    state = scenario.motion.state(sensors.sample_times(0.0, duration_s, gps_config.rate_hz))
    fixes = sensors.simulate_gps(state, gps_config, scenario.origin, np.random.default_rng(seed))
    frame = EnuFrame(*scenario.origin)
    gps_enu = frame.fixes_to_enu(fixes)
    gps_times = np.array([f.timestamp for f in fixes]) - gps_config.clock_offset_s
    truth = scenario.motion.state(gps_times).position
    step = np.linalg.norm(np.diff(truth[:, :2], axis=0, prepend=truth[:1, :2]), axis=1)
    travelled = np.cumsum(step)
    visual = drifting_track(truth[:, :2], drift_fraction, np.random.default_rng(seed + 1000))
    monitor = GpsMonitor(MonitorSettings())
    frame_times = np.arange(ALIGNED_AFTER_S, duration_s, 1 / 30)  # camera frames: outages are noticed between fixes
    next_frame = 0
    for t, g, v, d, true_en in zip(gps_times, gps_enu[:, :2], visual, travelled, truth[:, :2]):
        if t < ALIGNED_AFTER_S:
            continue
        while next_frame < len(frame_times) and frame_times[next_frame] < t:
            monitor.check_outage(float(frame_times[next_frame]))
            next_frame += 1
        monitor.update(float(t), g, v, float(d))
        if errors is not None:
            errors.append((float(t), float(np.linalg.norm(v + monitor.correction - true_en))))
    monitor.check_outage(duration_s)
    return monitor


def first(monitor: GpsMonitor, kind: str) -> float | None:
    return next((e.timestamp for e in monitor.events if e.kind == kind), None)
