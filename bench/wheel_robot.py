"""Seed 001's wheel robot: the EKF-SLAM (`estimator: ekf-slam`) through `evp run` on the rendered
wheel-robot room, and the wheel odometry of real robots integrated by the same motion model.
The issue's targets: metric ATE without scale alignment (SE3) <= 3 cm over the loop on 3 seeds
(the paper's converged camera error: under 3 cm), <= 10 ms per frame at 640x380 on one core with
up to 100 features in the state, and the real-time ratio.

Usage: python bench/wheel_robot.py [--out runs/wheel_robot] [--seeds 1 2 3] [--duration 60]
       [--fps 15] [--skip-rendered] [--skip-wheels]

Each seed is rendered by `evp sim wheel-robot-room` (640x380, 60 s: one loop of the room and a
half, at 15 fps, the paper's phone camera rate) into --out (an existing render with the same
options is reused) and run with `evp run --estimator ekf-slam` with BLAS held to one thread
(OPENBLAS_NUM_THREADS=1: one core). A row per seed: SE3 ATE (RMSE, max), path, features in the
state at most, features matched per frame (median), tracking ms per frame (median, p95), OpenCV's
ORB (1000 features) on the same frames in the same run and the ratio, the real-time ratio
(recorded seconds over processing seconds) and the filter's warnings (innovation consistency).

The wheel table integrates the wheel speeds and yaw rates of TU Chemnitz's labyrinth robot and
CMU's Plaza1 robot with `evp.fusion.planar_motion.dead_reckoning` (the EKF-SLAM's prediction)
from the truth's start pose (Plaza1: its first orientation; the labyrinth: the heading of its
first second of motion): end-point error, RMSE and max against the truth, and the path length's
error.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import yaml
from ground_vehicles import SHARED, first_motion_heading, horizontal_errors, yaw_of
from results import Results

from evp.fusion.planar_motion import dead_reckoning
from evp.io.registry import open_dataset

ROBOT_COLUMNS = [
    ("seed", "{seed}"),
    ("frames", "{frames}"),
    ("path (m)", "{path_m:.2f}"),
    ("SE3 ATE RMSE (m)", "{ate_se3_m:.4f}"),
    ("max (m)", "{ate_max_m:.4f}"),
    ("features (max)", "{features_max}"),
    ("matched/frame", "{matched_median:.0f}"),
    ("ms/frame median", "{tracking_ms_median:.1f}"),
    ("p95", "{tracking_ms_p95:.1f}"),
    ("OpenCV ORB ms", "{orb_ms_median:.1f}"),
    ("ratio to ORB", "{orb_ratio:.2f}"),
    ("real-time ratio", "{realtime_ratio:.1f}x"),
    ("warnings", "{warnings}"),
]
WHEEL_COLUMNS = [
    ("dataset", "{dataset}"),
    ("duration (s)", "{duration_s:.0f}"),
    ("path (m)", "{path_m:.1f}"),
    ("end-point error (m)", "{end_m:.2f}"),
    ("RMSE (m)", "{rmse_m:.2f}"),
    ("max (m)", "{max_m:.2f}"),
    ("path length error", "{path_error_percent:+.2f} %"),
]
ONE_CORE = {"OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}


def render(folder: Path, seed: int, duration: float, fps: float) -> None:
    description = folder / "sim.yaml"
    if description.is_file():
        options = yaml.safe_load(description.read_text())["options"]
        if options["seed"] == seed and options["fps"] == fps and options["duration_s"] in (None, duration):
            return
    command = [
        sys.executable,
        "-m",
        "evp.cli",
        "sim",
        "wheel-robot-room",
        "--out",
        str(folder),
        "--seed",
        str(seed),
        "--fps",
        str(fps),
        "--duration",
        str(duration),
    ]
    subprocess.run(command, check=True)


def robot_record(seed: int, folder: Path, out: Path) -> dict:
    subprocess.run(
        [sys.executable, "-m", "evp.cli", "run", str(folder), "--estimator", "ekf-slam", "--out", str(out)], check=True, env={**os.environ, **ONE_CORE}
    )
    metrics = json.loads((out / "metrics.json").read_text())
    timing = json.loads((out / "timing.json").read_text())
    section = metrics["ekf_slam"]
    times = np.loadtxt(out / "trajectory.tum", usecols=0)
    return {
        "seed": seed,
        "frames": metrics["frames"],
        "path_m": metrics["reference_path_length_m"],
        "ate_se3_m": metrics["rmse"],
        "ate_max_m": metrics["max"],
        "features_max": section["features_max"],
        "matched_median": section["matched_per_frame_median"],
        "tracking_ms_median": timing["tracking_ms_median"],
        "tracking_ms_p95": timing["tracking_ms_p95"],
        "orb_ms_median": timing["opencv_orb_ms_median"],
        "orb_ratio": timing["tracking_to_orb_ratio"],
        "realtime_ratio": (times[-1] - times[0]) / (sum(timing["tracking_ms"]) / 1000.0),
        "warnings": section["warnings_count"],
    }


def wheel_record(name: str, folder: str, start_yaw) -> dict:
    dataset = open_dataset(SHARED / folder)
    truth = dataset.ground_truth
    wheel = [w for w in dataset.wheel if w.timestamp >= truth.timestamps[0]]
    times = np.array([truth.timestamps[0], *(w.timestamp for w in wheel)])
    speeds = np.array([0.0, *(w.forward_speed_m_s for w in wheel)])
    rates = np.array([0.0, *(w.yaw_rate_rad_s for w in wheel)])
    poses = dead_reckoning((*truth.positions[0, :2], start_yaw(truth)), times, speeds, rates)
    track = np.column_stack([times, poses])
    track = track[track[:, 0] <= truth.timestamps[-1]]
    errors = horizontal_errors(track, truth.timestamps, truth.positions[:, :2])
    path = float(np.sum(np.linalg.norm(np.diff(track[:, 1:3], axis=0), axis=1)))
    return {
        "dataset": name,
        "duration_s": float(track[-1, 0] - track[0, 0]),
        "path_m": truth.path_length,
        "end_m": float(errors[-1]),
        "rmse_m": float(np.sqrt(np.mean(errors**2))),
        "max_m": float(errors.max()),
        "path_error_percent": 100.0 * (path / truth.path_length - 1.0),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", type=Path, default=Path("runs/wheel_robot"))
    parser.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3])
    parser.add_argument("--duration", type=float, default=60.0)
    parser.add_argument("--fps", type=float, default=15.0)
    parser.add_argument("--skip-rendered", action="store_true")
    parser.add_argument("--skip-wheels", action="store_true")
    args = parser.parse_args()
    results = Results("wheel_robot", "python bench/wheel_robot.py " + " ".join(sys.argv[1:]))
    if not args.skip_rendered:
        table = results.table("robot", ROBOT_COLUMNS, ["seed"], "EKF-SLAM on the rendered wheel-robot room (640x380, one core)")
        for seed in args.seeds:
            folder = args.out / f"robot_seed{seed}"
            render(folder, seed, args.duration, args.fps)
            print(table.add(robot_record(seed, folder, args.out / f"run_seed{seed}")), flush=True)
    if not args.skip_wheels:
        table = results.table("wheels", WHEEL_COLUMNS, ["dataset"], "Wheel odometry integrated by the EKF-SLAM's motion model, from the true start pose")
        print(table.add(wheel_record("tuc_labyrinth", "tuc_labyrinth_wheel_odometry", first_motion_heading)), flush=True)
        print(table.add(wheel_record("cmu_plaza1", "cmu_plaza1_wheel_odometry", lambda t: yaw_of(t.quats_xyzw[0]))), flush=True)


if __name__ == "__main__":
    main()
