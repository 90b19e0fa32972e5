"""Seed 002 (visual odometry aligned to GPS and barometer) on simulated flights shaped like its
Table I, and the GPS spoofing/jamming detector's figures.

Each flight is rendered at 10 fps (the GPS rate the paper down-sampled its video to; the
flights of `evp experiment seed002-tables2-5`, evp/experiments/seed002_flights.py), run
through EVP's visual odometry, aligned to GPS over the 70 s after reaching the target altitude,
and scored against the true position (and against GPS, as the paper does) on the rest of the
flight. The alignment alone is also scored on a modelled visual track (truth in its own frame,
with 0.5 % scale and heading errors); the detector on seeded flights with pull-off and jump
spoofing, clean flights and a jamming outage.

Usage: python bench/gps_alignment.py [--flights A,B,...] [--skip-rendered]

Prints three tables: rendered flights (aligned share, mean and largest error against truth and
GPS near the target altitude and overall, wall time), modelled tracks (errors, model chosen) and
the detector (time to alarm, false alarms per hour, outage handling, each with its target).
`--skip-rendered` leaves out the rendered flights (the slow part: minutes per flight). Needs no
shared data.
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from results import Results

from evp.config import AlignmentSettings
from evp.eval.statistics import error_statistics
from evp.experiments.seed002_flights import TABLE_I, flight_params, fly
from evp.sim.monitor_trials import drifting_track, first, monitor_run
from evp.sim.scenarios import SimOptions
from evp.sim.sensors import GpsConfig

FLIGHT_COLUMNS = [
    ("flight", "{flight}"),
    ("s", "{duration_s:.0f}"),
    ("target m", "{altitude_m:.0f}"),
    ("m/s", "{speed_m_s:.0f}"),
    ("aligned segment", "{aligned_percent:.0f} %"),
    ("near: mean vs truth (m)", "{near_mean_vs_truth_m:.2f}"),
    ("near: max vs truth", "{near_max_vs_truth_m:.2f}"),
    ("near: mean vs GPS", "{near_mean_vs_gps_m:.2f}"),
    ("near: max vs GPS", "{near_max_vs_gps_m:.2f}"),
    ("all: mean vs GPS", "{all_mean_vs_gps_m:.2f}"),
    ("all: max vs GPS", "{all_max_vs_gps_m:.2f}"),
    ("wall s", "{wall_s:.0f}"),
]
MODEL_COLUMNS = [
    ("flight", "{flight}"),
    ("s", "{duration_s:.0f}"),
    ("target m", "{altitude_m:.0f}"),
    ("m/s", "{speed_m_s:.0f}"),
    ("near: mean vs truth (m)", "{near_mean_vs_truth_m:.2f}"),
    ("near: max vs truth (m)", "{near_max_vs_truth_m:.2f}"),
    ("model", "{model}"),
]
DETECTOR_COLUMNS = [("test", "{test}"), ("result", "{result}"), ("target", "{target}")]


def flight_record(name: str, quick: bool = False) -> dict:
    """One Table I flight as ``evp experiment seed002-tables2-5`` runs it (3D+baro row)."""
    params = flight_params(name, quick)
    start = time.perf_counter()
    record = fly(**params)
    mode = record["3d+baro"]
    nan = {"mean": float("nan"), "max": float("nan")}
    near_truth, near_gps = mode["near_target_vs_truth"] or nan, mode["near_target"] or nan
    return {
        "flight": name,
        "duration_s": params["duration_s"],
        "altitude_m": params["altitude_m"],
        "speed_m_s": params["speed_m_s"],
        "aligned_percent": record["tracked_percent"],
        "near_mean_vs_truth_m": near_truth["mean"],
        "near_max_vs_truth_m": near_truth["max"],
        "near_mean_vs_gps_m": near_gps["mean"],
        "near_max_vs_gps_m": near_gps["max"],
        "all_mean_vs_gps_m": mode["whole"]["mean"],
        "all_max_vs_gps_m": mode["whole"]["max"],
        "wall_s": time.perf_counter() - start,
    }


def model_track_record(name: str, duration: float, altitude: float, drift_fraction: float = 0.005) -> dict:
    """The same flight with the visual track modelled (truth in its own frame and scale, with scale
    and heading errors of ``drift_fraction``, see monitor_trials.drifting_track): the alignment's
    own accuracy."""
    from scipy.spatial.transform import Rotation

    from evp.fusion.geodesy import EnuFrame
    from evp.fusion.gps_alignment import align_flight
    from evp.fusion.gps_input import clean_gps
    from evp.sim import sensors
    from evp.sim.scenarios import build_scenario
    from evp.types import Trajectory

    speed = 4.0 + (ord(name) % 5)
    options = SimOptions(duration_s=duration, altitude_m=altitude, speed_m_s=speed, relief=False, seed=ord(name))
    scenario = build_scenario("drone-flight", options)
    rng = np.random.default_rng(ord(name))
    times = np.arange(0.0, duration, 0.1)
    truth = scenario.motion.state(times).position
    visual = drifting_track(truth, drift_fraction, rng)
    R = Rotation.from_euler("zyx", [rng.uniform(0, 360), 2, -3], degrees=True).as_matrix()
    odometry = Trajectory((visual @ R) * 0.03, np.tile([0.0, 0.0, 0.0, 1.0], (len(times), 1)), times)
    gps = clean_gps(
        sensors.simulate_gps(scenario.motion.state(sensors.sample_times(0, duration, 10.0)), options.gps, scenario.origin, rng), EnuFrame(*scenario.origin)
    )
    baro_samples = sensors.simulate_baro(scenario.motion.state(times), options.baro, scenario.origin[2], rng)
    up = np.array([b.altitude_m for b in baro_samples]) - baro_samples[0].altitude_m
    baro = Trajectory(np.column_stack([np.zeros(len(up)), np.zeros(len(up)), up]), odometry.quats_xyzw, times)
    window = min(70.0, 0.5 * (duration - 2 * altitude / 3.0))
    result = align_flight(odometry, gps, baro, AlignmentSettings(target_altitude_m=altitude + 0.3, window_s=window))
    after = times > result.window[1]
    errors = np.linalg.norm(result.aligned.positions[after, :2] - truth[after, :2], axis=1)
    near = np.abs(truth[after, 2] - altitude - 0.3) < 2.0
    stats = error_statistics(errors[near])
    return {
        "flight": name,
        "duration_s": duration,
        "altitude_m": altitude,
        "speed_m_s": speed,
        "near_mean_vs_truth_m": stats["mean"],
        "near_max_vs_truth_m": stats["max"],
        "model": result.chosen["model"],
    }


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--flights", default=",".join(TABLE_I))
    parser.add_argument("--skip-rendered", action="store_true", help="only the modelled-track and detector tables (fast)")
    args = parser.parse_args()
    command = f"python bench/gps_alignment.py --flights {args.flights}" + (" --skip-rendered" if args.skip_rendered else "")
    print(f"command: {command}\n")
    results = Results("gps_alignment", command)
    caption = "Alignment (3d+baro, grid-searched model), errors on the part after the 70 s phase (half the time at altitude when shorter); 'near' = |z - target| < 2 m"
    print(caption)
    flights = results.table("rendered", FLIGHT_COLUMNS, key=["flight"], caption=caption)
    print(flights.header())
    for name in [] if args.skip_rendered else args.flights.split(","):
        print(flights.add(flight_record(name)), flush=True)
    caption = "Alignment alone: the visual track modelled as truth (own frame, scale) with 0.5 % scale and heading errors"
    print(f"\n{caption}")
    modelled = results.table("modelled", MODEL_COLUMNS, key=["flight"], caption=caption)
    print(modelled.header())
    for name in args.flights.split(","):
        duration, _, altitude = TABLE_I[name]
        print(modelled.add(model_track_record(name, duration, altitude)), flush=True)
    caption = "Spoofing / jamming detector (seeded flights, visual track with 0.5 % scale and heading errors, GPS 1.5 m Gauss-Markov + white)"
    print(f"\n{caption}")
    detector = results.table("detector", DETECTOR_COLUMNS, key=["test"], caption=caption)
    pulls = [first(monitor_run(GpsConfig(spoof_start_s=150.0, spoof_rate_m_s=5.0, spoof_direction_deg=37.0 * s), s), "spoofing_alarm") for s in range(10)]
    jumps = [
        first(monitor_run(GpsConfig(spoof_start_s=150.0, spoof_mode="jump", spoof_jump_m=50.0, spoof_direction_deg=37.0 * s), s), "spoofing_alarm")
        for s in range(10)
    ]
    clean = [(s, 400.0) for s in range(20)]
    false_alarms = sum(first(monitor_run(GpsConfig(), s, d), "spoofing_alarm") is not None for s, d in clean)
    hours = sum(d - 70.0 for _, d in clean) / 3600
    outage = monitor_run(GpsConfig(outages=[(120.0, 60.0)]), 5)
    print(detector.header())
    pull_delays = [p - 150 for p in pulls]
    rows = [
        ("5 m/s pull-off, time to alarm (10 flights)", f"max {max(pull_delays):.1f} s, median {np.median(pull_delays):.1f} s", "<= 5 s"),
        ("50 m jump, time to alarm (10 flights)", f"max {max(j - 150 for j in jumps):.1f} s", "<= 1 s"),
        ("false alarms, clean flights", f"{false_alarms} in {hours:.1f} h", "0 in >= 1 h"),
        (
            "60 s jamming outage",
            f"lost at +{first(outage, 'gps_lost') - 120:.1f} s, back at +{first(outage, 'gps_back') - 120:.1f} s, trust restored at +{first(outage, 'trust_restored') - 120:.1f} s",
            "reported",
        ),
    ]
    for test, result, target in rows:
        print(detector.add({"test": test, "result": result, "target": target}))


if __name__ == "__main__":
    main()
