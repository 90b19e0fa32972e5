"""The navigation stage on rendered datasets: `evp run` on the indoor circle (IMU and barometer,
seed 000's test) and the wheel-robot room (IMU, wheels with their gyro, seed 001's robot), each
rendered by `evp sim`. The issue's targets: the circle's fused trajectory within 3 cm after SE3
alignment (no scale) with the scale known within 5 s of the walking start; the robot's within 2 %
of its path.

Usage: python bench/navigation_rendered.py [--out runs/navigation_rendered] [--circle-seeds 1 2 3]
       [--robot-seeds 1 2] [--robot-duration 30] [--real euroc_mh_01_easy_moving_360 ...]
       [--reuse NAME=FOLDER ...] [--resume]

Each case is rendered into --out (unless --reuse names an existing render of it, e.g.
circle1=/tmp/circ1; the render's sim.yaml must show the same options) and run with `evp run`
(defaults: SLAM, mapping inline, the navigation stage; with --resume a case whose run folder
already holds metrics.json is read, not run again: a circle takes ~5 CPU minutes). A row per case: SE3 ATE of the fused
trajectory (trajectory.tum: the stage run again on SLAM's refined trajectory) and as a share of
the path, that of the fused poses as answered live, the Sim3 ATE of SLAM alone (trajectory_visual.tum), when
the filter started and when its scale became known (sigma below navigation.scale_known_sigma),
both from the start of motion, the final scale error against the Sim3 scale of SLAM's poses to
the truth, and the sensors the filter used.

`--real` adds shared sequences with an IMU (../shared/data; default EuRoC MH01, issue 30's real
visual-inertial target: SE3 ATE <= 3 cm, scale within 2 %), run the same way, their times from
the first frame.

A second table isolates the filter from SLAM: the same stage and telemetry, fed the truth's
camera poses in a map of scale 1/1.3 instead of SLAM's (what the filter does with consistent
visual poses).
"""

from __future__ import annotations

import argparse
import csv
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import yaml
from results import Results

from evp.config import Settings
from evp.estimator import GivenPoses
from evp.eval.evaluate import evaluate
from evp.fusion.navigation_stage import NavigationStage
from evp.io.registry import open_dataset
from evp.io.trajectory import read_trajectory
from evp.pipeline import run_frames
from evp.types import Frame

# both scenarios stand still this long before moving (circle_indoor's `times - 2.0`,
# wheel_robot_room's `paths.hold(..., 2.0)`)
STANDING_START_S = 2.0
SHARED = Path(__file__).resolve().parents[2] / "shared" / "data"
CIRCLE = {"scenario": "circle-indoor", "duration_s": 26.0, "fps": 30.0}  # bench/run_sequences.py's render
ROBOT_FPS = 20.0  # the robot's forward camera at 0.3 m/s moves 1.5 cm a frame

COLUMNS = [
    ("case", "{case}"),
    ("path (m)", "{path_m:.2f}"),
    ("SE3 ATE fused (m)", "{ate_se3_m:.4f}"),
    ("SE3 ATE / path", "{ate_se3_path_percent:.2f} %"),
    ("SE3 ATE fused live (m)", "{ate_se3_live_m:.4f}"),
    ("Sim3 ATE SLAM alone (m)", "{ate_sim3_visual_m:.4f}"),
    ("filter started (s after motion)", "{started_s:.2f} ({start_source})"),
    ("scale known (s after motion)", "{scale_known_s:.2f}"),
    ("final scale error", "{scale_error_percent:+.2f} %"),
    ("sensors used", "{sensors}"),
]


def _render(case: dict, folder: Path) -> None:
    from evp.sim.generate import generate
    from evp.sim.scenarios import SimOptions

    generate(case["scenario"], SimOptions(duration_s=case["duration_s"], fps=case["fps"], seed=case["seed"]), folder, workers=2)


def _same_render(folder: Path, case: dict) -> bool:
    description = yaml.safe_load((folder / "sim.yaml").read_text())
    options = description["options"]
    return description["scenario"] == case["scenario"] and all(options[k] == case[k] for k in ("duration_s", "fps", "seed"))


def _record(name: str, folder: Path, out: Path, resume: bool, motion_start: float) -> dict:
    if not (resume and (out / "metrics.json").is_file()):
        subprocess.run([sys.executable, "-m", "evp.cli", "run", str(folder), "--out", str(out)], check=True)
    metrics = json.loads((out / "metrics.json").read_text())
    navigation = metrics.get("navigation", {})
    known = None
    if (out / "navigation.csv").is_file():
        with (out / "navigation.csv").open() as handle:
            known = next((float(row["timestamp"]) for row in csv.DictReader(handle) if row["scale_known"] == "1"), None)
    path = metrics.get("reference_path_length_m")  # the truth's path over the frames SLAM tracked
    started = navigation.get("initialised_at_s")
    status = navigation.get("status", "")
    return {
        "case": name,
        "path_m": path,
        "ate_se3_m": navigation.get("ate_se3_rmse_m"),
        "ate_se3_path_percent": None if navigation.get("ate_se3_rmse_m") is None or not path else 100 * navigation["ate_se3_rmse_m"] / path,
        "ate_se3_live_m": navigation.get("live_ate_se3_rmse_m"),
        "ate_sim3_visual_m": metrics.get("rmse"),
        "started_s": None if started is None else started - motion_start,
        "start_source": "wheels" if "wheel odometry" in status else "visual-inertial",
        "scale_known_s": None if known is None else known - motion_start,
        "scale_error_percent": None if navigation.get("scale_error") is None else 100 * navigation["scale_error"],
        "sensors": ", ".join(navigation.get("sensors_used", [])),
        "status": status,
    }


TRUTH_MAP_SCALE = 1.3  # metres per map unit of the truth-pose map: any scale the filter must find
TRUTH_COLUMNS = [
    ("case, stage on the truth's camera poses", "{case}"),
    ("SE3 ATE fused (m)", "{ate_se3_m:.4f}"),
    ("filter started (s after motion)", "{started_s:.2f}"),
    ("scale known (s after motion)", "{scale_known_s:.2f}"),
    ("final scale error", "{scale_error_percent:+.2f} %"),
]


def _truth_record(name: str, folder: Path) -> dict:
    dataset = open_dataset(folder)
    stage = NavigationStage(dataset.T_body_cam)
    camera_truth = read_trajectory(folder / "groundtruth_cam0_tum.txt")  # the generator's, at the frame times
    frames = (Frame(float(t), np.zeros((1, 1), np.uint8), i) for i, t in enumerate(dataset.frame_times))
    map_poses = camera_truth.poses.copy()
    map_poses[:, :3, 3] /= TRUTH_MAP_SCALE  # the truth's camera poses in a map of scale 1/TRUTH_MAP_SCALE
    result = run_frames(GivenPoses(camera_truth.timestamps, map_poses, tolerance_s=1e-3), frames, stages=[stage], telemetry=dataset.telemetry())
    eval_settings = Settings().eval.model_copy(update={"align": "se3", "max_time_diff_s": 0.001})
    motion_start = yaml.safe_load((folder / "sim.yaml").read_text())["clock_epoch_s"] + STANDING_START_S
    known = next((r.output.timestamp for r in stage.records if r.output.scale_known), None)
    metric = result.metric_trajectory()
    return {
        "case": name,
        "ate_se3_m": evaluate(dataset.ground_truth, metric, eval_settings).summary()["rmse"] if len(metric) >= 3 else None,
        "started_s": None if stage.initialised_at is None else stage.initialised_at - motion_start,
        "scale_known_s": None if known is None else known - motion_start,
        "scale_error_percent": 100 * (stage.records[-1].output.scale / TRUTH_MAP_SCALE - 1) if stage.records else None,
    }


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--out", type=Path, default=Path("runs/navigation_rendered"))
    parser.add_argument("--circle-seeds", nargs="*", type=int, default=[1, 2, 3])
    parser.add_argument("--robot-seeds", nargs="*", type=int, default=[1, 2])
    parser.add_argument("--robot-duration", type=float, default=30.0)
    parser.add_argument("--real", nargs="*", default=["euroc_mh_01_easy_moving_360"], help="shared sequences with an IMU (../shared/data)")
    parser.add_argument("--resume", action="store_true", help="read the runs already in --out instead of running them again")
    parser.add_argument("--reuse", nargs="*", default=[], metavar="NAME=FOLDER", help="an existing render for a case, e.g. circle1=/tmp/circ1")
    args = parser.parse_args()
    reuse = dict(item.split("=", 1) for item in args.reuse)
    cases = {f"circle{seed}": {**CIRCLE, "seed": seed} for seed in args.circle_seeds}
    cases |= {f"robot{seed}": {"scenario": "wheel-robot-room", "duration_s": args.robot_duration, "fps": ROBOT_FPS, "seed": seed} for seed in args.robot_seeds}
    results = Results("navigation_rendered", "python bench/navigation_rendered.py " + " ".join(sys.argv[1:]))
    table = results.table(
        "navigation_rendered",
        COLUMNS,
        key=["case"],
        caption="`evp run` with the navigation stage on rendered datasets (640x380; times from the end of the 2 s standing start) and on shared sequences with an IMU",
    )
    print(table.header(), flush=True)
    truth_rows = []
    for name, case in cases.items():
        folder = Path(reuse[name]) if name in reuse else args.out / f"{name}_data"
        if name in reuse and not _same_render(folder, case):
            raise SystemExit(f"--reuse {name}: {folder}/sim.yaml was rendered with other options than {case}")
        if name not in reuse and not (folder / "sim.yaml").is_file():
            _render(case, folder)
        label = f"{case['scenario']} seed {case['seed']} ({case['duration_s']:g} s, {case['fps']:g} fps)"
        motion_start = yaml.safe_load((folder / "sim.yaml").read_text())["clock_epoch_s"] + STANDING_START_S
        print(table.add(_record(label, folder, args.out / name, args.resume, motion_start)), flush=True)
        truth_rows.append((label, folder))
    for name in args.real:
        folder = SHARED / name
        if not folder.is_dir():
            print(f"| {name} | missing (../shared/data) |", flush=True)
            continue
        label = f"{name} (real; times from the first frame)"
        print(table.add(_record(label, folder, args.out / name, args.resume, open_dataset(folder).frame_times[0])), flush=True)
    truth = results.table("navigation_rendered_truth_poses", TRUTH_COLUMNS, key=["case"], caption="the same stage and telemetry on the truth's camera poses")
    print(truth.header(), flush=True)
    for label, folder in truth_rows:
        print(truth.add(_truth_record(label, folder)), flush=True)


if __name__ == "__main__":
    main()
