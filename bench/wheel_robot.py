"""Seed 001's wheel robot: the EKF-SLAM (`estimator: ekf-slam`) through `evp run` on the rendered
wheel-robot room, and the wheel odometry of real robots integrated by the same motion model.
The issue's targets: metric ATE without scale alignment (SE3) <= 3 cm over the loop on 3 seeds
(the paper's converged camera error: under 3 cm), <= 10 ms per frame at 640x380 on one core with
up to 100 features in the state, and the real-time ratio.

Usage: python bench/wheel_robot.py [--out runs/wheel_robot] [--seeds 1 2 3] [--duration 60]
       [--fps 15] [--skip-rendered] [--skip-wheels] [--wifi] [--wifi-long SECONDS]
       [--baseline-src DIR --baseline-label TEXT]

Each seed is rendered by `evp sim wheel-robot-room` (640x380, 60 s: one loop of the room and a
half, at 15 fps, the paper's phone camera rate) into --out (an existing render with the same
options is reused) and run with `evp run --estimator ekf-slam` with BLAS held to one thread
(OPENBLAS_NUM_THREADS=1 and OpenCV's OPENCV_FOR_THREADS_NUM=1: one core). A row per seed: SE3
ATE (RMSE, max), path, features in the state at most, features matched per frame (median),
tracking ms per frame (median, p95), OpenCV's ORB (1000 features) on the same frames in the same
run and the ratio, the same three as thread CPU time (the machine's load does not count in it),
the real-time ratio (recorded seconds over processing seconds) and the filter's warnings
(innovation consistency). --baseline-src DIR runs each seed first with the evp package of
another checkout (DIR/src: the code before a change), its rows labelled ``baseline
--baseline-label``, so before and after are timed in one run on the same machine.

--wifi adds the WiFi table: each seed with and without the rendered WiFi scans fused
(``wifi.radio_map``: the room's survey, wifi_radio_map.npz, written beside the render when it
lacks one) in three cases: the start known in the room's frame (``ekf_slam.start_pose`` from the
truth's first body pose, 5 cm / 2 deg: a robot leaving its surveyed dock), the same with the
wheels degraded (speeds x --degraded-scale, a wrong wheel radius, and the gyro off by
--degraded-gyro rad/s, an uncalibrated turn-on bias), and the start --start-error m off with a
1-sigma of as much (the robot put down somewhere in the room, its heading known). Absolute ATE
(no alignment: what WiFi bounds) and SE3 ATE, for the EKF-SLAM (camera + wheels + gyro) and for
its filter on the wheels and gyro alone (no frames: dead reckoning), in-process.

--wifi-long SECONDS adds the long table: the EKF-SLAM's filter on the wheels and gyro alone
(no frames, the room's sensors sampled without rendering) over SECONDS of its loop (400 s: ten
laps), with and without the WiFi fixes, the wheels as simulated and degraded as above, from the
known start: whether the fixes hold the error at their own where dead reckoning's grows (in
this room they do not: the k-NN fixes are biased toward the room's middle, docs/decisions.md).

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
    ("code", "{code}"),
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
    ("CPU ms/frame", "{cpu_ms_median:.1f}"),
    ("ORB CPU ms", "{orb_cpu_ms_median:.1f}"),
    ("CPU ratio to ORB", "{orb_cpu_ratio:.2f}"),
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
ONE_CORE = {"OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1", "OPENCV_FOR_THREADS_NUM": "1"}
THIS_CHECKOUT = "this checkout"


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


def robot_record(seed: int, folder: Path, out: Path, code: str = THIS_CHECKOUT, src: Path | None = None) -> dict:
    """``evp run --estimator ekf-slam`` on one seed's render, on one core; ``src``: the ``src``
    folder of another checkout to run instead of this one (``code`` labels the row)."""
    env = {**os.environ, **ONE_CORE, **({"PYTHONPATH": str(src)} if src is not None else {})}
    subprocess.run([sys.executable, "-m", "evp.cli", "run", str(folder), "--estimator", "ekf-slam", "--out", str(out)], check=True, env=env)
    metrics = json.loads((out / "metrics.json").read_text())
    timing = json.loads((out / "timing.json").read_text())
    section = metrics["ekf_slam"]
    times = np.loadtxt(out / "trajectory.tum", usecols=0)
    return {
        "seed": seed,
        "code": code,
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
        "cpu_ms_median": timing.get("feed_cpu_ms_median"),
        "orb_cpu_ms_median": timing.get("opencv_orb_cpu_ms_median"),
        "orb_cpu_ratio": timing.get("feed_to_orb_cpu_ratio"),
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


WIFI_COLUMNS = [
    ("seed", "{seed}"),
    ("estimator", "{mode}"),
    ("wheels", "{wheels}"),
    ("start", "{start}"),
    ("WiFi", "{wifi}"),
    ("absolute ATE RMSE (m)", "{ate_abs_m:.3f}"),
    ("max (m)", "{ate_abs_max_m:.3f}"),
    ("SE3 ATE RMSE (m)", "{ate_se3_m:.3f}"),
    ("fixes fused / gated", "{fixes}"),
]


def degraded(dataset, scale: float, gyro_offset: float):
    """The dataset with its wheel speeds scaled by ``scale`` (a wrong wheel radius) and its yaw
    rates off by ``gyro_offset`` rad/s."""
    from dataclasses import replace

    wheel = [
        replace(
            w,
            wheel_speeds_m_s=tuple(v * scale for v in w.wheel_speeds_m_s),
            forward_speed_m_s=w.forward_speed_m_s * scale,
            yaw_rate_rad_s=w.yaw_rate_rad_s + gyro_offset,
        )
        for w in dataset.wheel
    ]
    return replace(dataset, wheel=wheel)


def start_pose(dataset) -> list[float]:
    """The truth's first body pose as ``ekf_slam.start_pose`` (x, y, heading deg)."""
    from evp.geometry.transforms import se3_inverse

    T = dataset.ground_truth.poses[0] @ se3_inverse(dataset.T_body_cam)
    return [float(T[0, 3]), float(T[1, 3]), float(np.degrees(np.arctan2(T[1, 0], T[0, 0])))]


def ate(truth, est) -> tuple[float, float, float]:
    """Absolute RMSE and max (no alignment) and SE3-aligned RMSE of ``est`` against ``truth``."""
    from evp.eval.association import associate
    from evp.eval.metrics import Alignment, align_trajectory, ape_translation

    ref, est = associate(truth, est, 0.02)
    absolute = ape_translation(ref, est)
    aligned = ape_translation(ref, align_trajectory(ref, est, Alignment.SE3)[0])
    return float(np.sqrt(np.mean(absolute**2))), float(absolute.max()), float(np.sqrt(np.mean(aligned**2)))


def dead_reckoning_trajectory(dataset, estimator):
    """The EKF-SLAM's filter fed the wheels (and WiFi) alone: the camera poses at the frames' stamps."""
    from evp.types import Trajectory

    poses, stamps = [], []
    records = iter(dataset.telemetry())
    pending = next(records, None)
    for t in dataset.frame_times:
        while pending is not None and pending.timestamp <= t:
            estimator.observe(pending)
            pending = next(records, None)
        estimator.slam.filter.extrapolate(t)
        R, centre = estimator.slam.filter.camera_pose()
        pose = np.eye(4)
        pose[:3, :3], pose[:3, 3] = R, centre
        poses.append(pose), stamps.append(t)
    return Trajectory.from_poses(np.array(poses), np.array(stamps), "dead reckoning")


def wifi_records(seed: int, folder: Path, scale: float, gyro_offset: float, start_error: float) -> list[dict]:
    from evp.config import Settings
    from evp.run_setup import camera_for, ekf_slam_estimator, estimate, resolve_settings

    radio_map = folder / "wifi_radio_map.npz"
    if not radio_map.is_file():
        from evp.sim.generate import write_wifi_survey
        from evp.sim.scenarios import SimOptions, build_scenario

        options = SimOptions.model_validate(yaml.safe_load((folder / "sim.yaml").read_text())["options"])
        write_wifi_survey(build_scenario("wheel-robot-room", options), options, folder)
    original = open_dataset(folder)
    start = start_pose(original)
    away = [start[0] + start_error / np.sqrt(2), start[1] - start_error / np.sqrt(2), start[2]]
    cases = [
        ("as rendered", "known", original, {"start_pose": start}),
        (f"speeds x{scale:g}, gyro {gyro_offset:+g} rad/s", "known", degraded(original, scale, gyro_offset), {"start_pose": start}),
        ("as rendered", f"{start_error:g} m off", original, {"start_pose": away, "start_position_sigma_m": start_error}),
    ]
    records = []
    for wheels, start_case, dataset, ekf_slam in cases:
        for wifi in (False, True):
            overrides = {"estimator": "ekf-slam", "ekf_slam": ekf_slam, "wifi": {"radio_map": str(radio_map) if wifi else None}}
            settings = resolve_settings(Settings.model_validate(overrides), dataset)
            dead = ekf_slam_estimator(camera_for(dataset, settings), settings, dataset)
            result, _, estimator = estimate(dataset, settings)
            for mode, trajectory, used in (("ekf-slam", result.trajectory(), estimator), ("wheels+gyro only", dead_reckoning_trajectory(dataset, dead), dead)):
                fixes = used.slam.filter.fixes
                absolute, worst, se3 = ate(dataset.ground_truth, trajectory)
                accepted = sum(1 for f in fixes if f.accepted)
                record = {"seed": seed, "mode": mode, "wheels": wheels, "start": start_case, "wifi": "fused" if wifi else "off"}
                record.update(
                    {"ate_abs_m": absolute, "ate_abs_max_m": worst, "ate_se3_m": se3, "fixes": f"{accepted} / {len(fixes) - accepted}" if wifi else "-"}
                )
                records.append(record)
    return records


LONG_COLUMNS = [
    ("seed", "{seed}"),
    ("duration (s)", "{duration_s:.0f}"),
    ("wheels", "{wheels}"),
    ("WiFi", "{wifi}"),
    ("error RMSE (m)", "{rmse_m:.2f}"),
    ("max (m)", "{max_m:.2f}"),
    ("last minute, mean (m)", "{last_minute_m:.2f}"),
    ("fixes fused / gated", "{fixes}"),
]


def long_drive_records(seed: int, duration: float, scale: float, gyro_offset: float) -> list[dict]:
    """The EKF-SLAM's filter on the wheels and gyro alone (no frames) over ``duration`` s of the
    robot room's loop (the sensors sampled without rendering), with and without the WiFi scans,
    as rendered and degraded: the horizontal error of the robot against the truth once a second."""
    from dataclasses import replace

    from evp.config import EkfSlamSettings, WifiSettings
    from evp.ekf_slam.estimator import EkfSlamEstimator
    from evp.sim.scenarios import SimOptions, wheel_robot_room
    from evp.sim.sensors import sample_times, simulate_wheels, simulate_wifi, simulate_wifi_survey
    from evp.wifi.methods import method_named
    from evp.wifi.positioning import wifi_locator

    options = SimOptions(seed=seed, duration_s=duration)
    scenario = wheel_robot_room(options)

    def state(rate: float):
        return scenario.motion.state(sample_times(scenario.motion.start, scenario.motion.end, rate))

    wheels = simulate_wheels(state(options.wheel.rate_hz), options.wheel, np.random.default_rng([seed, 4]))
    scans = simulate_wifi(state(options.wifi.rate_hz), options.wifi, scenario.access_points, np.random.default_rng([seed, 6]))
    survey = simulate_wifi_survey(state(10.0).position, options.wifi, scenario.access_points, np.random.default_rng([seed, 7]))
    wifi = WifiSettings()
    locator = wifi_locator(survey, method_named(wifi.method, survey, wifi), wifi.not_detected_dbm, wifi.place_tolerance_m)
    start = state(options.wheel.rate_hz)
    settings = EkfSlamSettings(start_pose=[*map(float, start.position[0, :2]), float(np.degrees(start.rotation[0].as_euler("ZYX")[0]))])
    truth = state(1.0)
    records = []
    cases = [("as rendered", 1.0, 0.0), (f"speeds x{scale:g}", scale, 0.0), (f"speeds x{scale:g}, gyro {gyro_offset:+g} rad/s", scale, gyro_offset)]
    for wheels_case, factor, offset in cases:
        wheel = [replace(w, forward_speed_m_s=w.forward_speed_m_s * factor, yaw_rate_rad_s=w.yaw_rate_rad_s + offset) for w in wheels]
        for fused in (False, True):
            estimator = EkfSlamEstimator(scenario.camera, scenario.T_body_cam, settings, locator if fused else None)
            stream = sorted([*wheel, *scans], key=lambda r: r.timestamp)
            errors, k = [], 0
            for t, position in zip(truth.time, truth.position):
                while k < len(stream) and stream[k].timestamp <= t:
                    estimator.observe(stream[k])
                    k += 1
                errors.append(np.linalg.norm(estimator.slam.filter.x[:2] - position[:2]))
            errors = np.array(errors)
            fixes = estimator.slam.filter.fixes
            accepted = sum(1 for f in fixes if f.accepted)
            records.append(
                {
                    "seed": seed,
                    "duration_s": duration,
                    "wheels": wheels_case,
                    "wifi": "fused" if fused else "off",
                    "rmse_m": float(np.sqrt(np.mean(errors**2))),
                    "max_m": float(errors.max()),
                    "last_minute_m": float(errors[-60:].mean()),
                    "fixes": f"{accepted} / {len(fixes) - accepted}" if fused else "-",
                }
            )
    return records


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", type=Path, default=Path("runs/wheel_robot"))
    parser.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3])
    parser.add_argument("--duration", type=float, default=60.0)
    parser.add_argument("--fps", type=float, default=15.0)
    parser.add_argument("--skip-rendered", action="store_true")
    parser.add_argument("--skip-wheels", action="store_true")
    parser.add_argument("--wifi", action="store_true", help="add the WiFi table (in-process, 4 EKF-SLAM runs per seed)")
    parser.add_argument("--degraded-scale", type=float, default=1.05, help="the degraded wheels' speed factor")
    parser.add_argument("--degraded-gyro", type=float, default=0.02, help="the degraded gyro's offset (rad/s)")
    parser.add_argument("--start-error", type=float, default=1.0, help="the unknown start's position error (m)")
    parser.add_argument("--baseline-src", type=Path, help="also run each seed, first, with the evp package of this checkout's src (before a change)")
    parser.add_argument("--baseline-label", default="", help="what the baseline is (its commit), after 'baseline' in the code column")
    parser.add_argument("--wifi-long", type=float, default=0.0, help="add the long WiFi table: the wheels alone over this many seconds (no rendering)")
    args = parser.parse_args()
    results = Results("wheel_robot", "python bench/wheel_robot.py " + " ".join(sys.argv[1:]))
    if not args.skip_rendered:
        table = results.table("robot", ROBOT_COLUMNS, ["seed", "code"], "EKF-SLAM on the rendered wheel-robot room (640x380, one core)")
        for seed in args.seeds:
            folder = args.out / f"robot_seed{seed}"
            render(folder, seed, args.duration, args.fps)
            if args.baseline_src is not None:
                label = f"baseline {args.baseline_label}".strip()
                print(table.add(robot_record(seed, folder, args.out / f"baseline_seed{seed}", label, (args.baseline_src / "src").resolve())), flush=True)
            print(table.add(robot_record(seed, folder, args.out / f"run_seed{seed}")), flush=True)
    if args.wifi:
        table = results.table(
            "wifi", WIFI_COLUMNS, ["seed", "mode", "wheels", "start", "wifi"], "WiFi fixes fused into the EKF-SLAM (radio map: the room's survey, wknn_cv)"
        )
        for seed in args.seeds:
            folder = args.out / f"robot_seed{seed}"
            render(folder, seed, args.duration, args.fps)
            for record in wifi_records(seed, folder, args.degraded_scale, args.degraded_gyro, args.start_error):
                print(table.add(record), flush=True)
    if args.wifi_long:
        table = results.table(
            "wifi_long", LONG_COLUMNS, ["seed", "duration_s", "wheels", "wifi"], "WiFi fixes bounding the wheels' drift: the EKF-SLAM's filter without frames"
        )
        for seed in args.seeds:
            for record in long_drive_records(seed, args.wifi_long, args.degraded_scale, args.degraded_gyro):
                print(table.add(record), flush=True)
    if not args.skip_wheels:
        table = results.table("wheels", WHEEL_COLUMNS, ["dataset"], "Wheel odometry integrated by the EKF-SLAM's motion model, from the true start pose")
        print(table.add(wheel_record("tuc_labyrinth", "tuc_labyrinth_wheel_odometry", first_motion_heading)), flush=True)
        print(table.add(wheel_record("cmu_plaza1", "cmu_plaza1_wheel_odometry", lambda t: yaw_of(t.quats_xyzw[0]))), flush=True)


if __name__ == "__main__":
    main()
