"""Each SLAM sequence replayed at its recorded frame rate, as the base station runs live: the
estimator always takes the newest frame, and a frame that arrives while it is busy is dropped
(`evp run --realtime`). Once with local mapping inline (mapped between frames) and once in its own
thread.

Usage: python bench/realtime_replay.py [--out runs/realtime] [--only euroc_mh_01_easy_moving_360|kitti_odom_06_f000-050|davis_slider_depth|circle ...]

Prints per sequence and mapping mode: frames fed and dropped, the share of all frames tracked in
trajectory.tum and answered live, ATE (Sim3, m), tracking ms with mapping running (median, p95),
mapping ms per keyframe, keyframes and the largest keyframe queue. "Fed" and "tracked" show
whether tracking plus mapping keep up with the camera. Needs ../shared/data; renders the circle.
Takes each sequence's duration twice, plus the final adjustments.
"""

from __future__ import annotations

import argparse
import json
import platform
import sys
import tempfile
from pathlib import Path

from results import Results
from run_sequences import SHARED, render_circle

from evp.config import Settings
from evp.io.registry import open_dataset
from evp.io.run_outputs import write_outputs
from evp.pipeline import run_dataset
from evp.run_setup import camera_for, make_estimator, resolve_settings

SEQUENCES = ["euroc_mh_01_easy_moving_360", "kitti_odom_06_f000-050", "davis_slider_depth"]
COLUMNS = [
    ("sequence", "{sequence}"),
    ("frame rate", "{fps:.0f} fps"),
    ("mapping", "{mapping}"),
    ("fed", "{frames_fed}"),
    ("dropped", "{frames_dropped}"),
    ("tracked of all frames (trajectory.tum; live)", "{tracked_percent:.1f} %; {tracked_live_percent:.1f} %"),
    ("ATE Sim3 (m)", "{ate_m:.4f}"),
    ("tracking ms median", "{tracking_ms_median:.1f}"),
    ("p95", "{tracking_ms_p95:.1f}"),
    ("mapping ms/keyframe", "{mapping_ms_median:.0f}"),
    ("keyframes", "{keyframes}"),
    ("keyframe queue max", "{keyframe_queue_max}"),
]


def _record(name: str, path: Path, mapping: str, out: Path) -> dict:
    settings = Settings.model_validate({"estimator": "slam", "slam": {"mapping": mapping}})
    dataset = open_dataset(path)
    settings = resolve_settings(settings, dataset)
    estimator = make_estimator(camera_for(dataset, settings), settings, dataset)
    result = run_dataset(dataset, estimator, realtime_speed=1.0)
    metrics = write_outputs(result, dataset, settings, out / f"{name}-{mapping}")
    timing = json.loads((out / f"{name}-{mapping}" / "timing.json").read_text())
    rate = (dataset.num_frames - 1) / (dataset.frame_times[-1] - dataset.frame_times[0])
    return {
        "sequence": name,
        "fps": rate,
        "mapping": mapping,
        "frames_fed": metrics["frames_fed"],
        "frames_dropped": metrics["frames_dropped"],
        "tracked_percent": 100 * metrics["tracked_fraction"],
        "tracked_live_percent": 100 * metrics["tracked_live_frames"] / metrics["frames"],
        "ate_m": metrics.get("rmse"),
        "tracking_ms_median": timing["tracking_ms_median"],
        "tracking_ms_p95": timing["tracking_ms_p95"],
        "mapping_ms_median": timing.get("mapping_ms_median"),
        "keyframes": len(estimator.mapping_ms),
        "keyframe_queue_max": timing["keyframe_queue_max"],
    }


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--out", type=Path, default=Path("runs/realtime"))
    parser.add_argument("--only", nargs="+", choices=[*SEQUENCES, "circle"], help="just these sequences")
    args = parser.parse_args()
    only = f" --only {' '.join(args.only)}" if args.only else ""
    command = f"python bench/realtime_replay.py --out {args.out}{only}"
    print(f"command: {command}  ({platform.node()}, {platform.machine()})\n")
    table = Results("realtime_replay", command).table(
        "replays", COLUMNS, key=["sequence", "mapping"], caption="Each sequence at its recorded frame rate, newest frame first"
    )
    print(table.header())
    with tempfile.TemporaryDirectory() as tmp:
        for name in args.only or [*SEQUENCES, "circle"]:
            path = render_circle(Path(tmp) / "circle") if name == "circle" else SHARED / name
            if not path.exists():
                print(f"| {name} | missing |" + " |" * 10)
                continue
            for mapping in ("inline", "thread"):
                print(table.add(_record(name, path, mapping, args.out)))
                sys.stdout.flush()


if __name__ == "__main__":
    main()
