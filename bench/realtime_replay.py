"""Live behaviour: each SLAM sequence replayed at its recorded frame rate (`evp run --realtime`),
the estimator always given the newest frame as on the base station, with local mapping inline
(mapped between frames, the station's default) and in its own thread.

Usage: python bench/realtime_replay.py [--out runs/realtime] [--only NAME ...]

A frame that arrives while the estimator is busy is dropped, so "fed" and "tracked" show whether
tracking plus mapping keep up with the camera; tracking ms are measured with mapping running.
"""

from __future__ import annotations

import argparse
import json
import platform
import sys
import tempfile
from pathlib import Path

from run_sequences import SHARED, render_circle

from evp.config import Settings
from evp.io.registry import open_dataset
from evp.pipeline import run_dataset, write_outputs
from evp.run_setup import camera_for, make_estimator, resolve_settings

SEQUENCES = ["euroc_mh_01_easy_moving_360", "kitti_odom_06_f000-050", "davis_slider_depth"]
TABLE_HEADER = (
    "| sequence | frame rate | mapping | fed | dropped | tracked of all frames (trajectory.tum; live) | ATE Sim3 (m) | tracking ms median | p95 "
    "| mapping ms/keyframe | keyframes | keyframe queue max |\n" + "|---" * 12 + "|"
)


def _row(name: str, path: Path, mapping: str, out: Path) -> str:
    settings = Settings.model_validate({"estimator": "slam", "slam": {"mapping": mapping}})
    dataset = open_dataset(path)
    settings = resolve_settings(settings, dataset)
    estimator = make_estimator(camera_for(dataset, settings), settings, dataset)
    result = run_dataset(dataset, estimator, realtime_speed=1.0)
    metrics = write_outputs(result, dataset, settings, out / f"{name}-{mapping}")
    timing = json.loads((out / f"{name}-{mapping}" / "timing.json").read_text())
    ate = f"{metrics['rmse']:.4f}" if "rmse" in metrics else "n/a"
    rate = (dataset.num_frames - 1) / (dataset.frame_times[-1] - dataset.frame_times[0])
    return (
        f"| {name} | {rate:.0f} fps | {mapping} | {metrics['frames_fed']} | {metrics['frames_dropped']} "
        f"| {100 * metrics['tracked_fraction']:.1f} %; {100 * metrics['tracked_live_frames'] / metrics['frames']:.1f} % | {ate} | {timing['tracking_ms_median']:.1f} | {timing['tracking_ms_p95']:.1f} "
        f"| {timing.get('mapping_ms_median', float('nan')):.0f} | {len(estimator.mapping_ms)} | {timing['keyframe_queue_max']} |"
    )


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--out", type=Path, default=Path("runs/realtime"))
    parser.add_argument("--only", nargs="+", choices=[*SEQUENCES, "circle"], help="just these sequences")
    args = parser.parse_args()
    only = f" --only {' '.join(args.only)}" if args.only else ""
    print(f"command: python bench/realtime_replay.py --out {args.out}{only}  ({platform.node()}, {platform.machine()})\n")
    print(TABLE_HEADER)
    with tempfile.TemporaryDirectory() as tmp:
        for name in args.only or [*SEQUENCES, "circle"]:
            path = render_circle(Path(tmp) / "circle") if name == "circle" else SHARED / name
            if not path.exists():
                print(f"| {name} | missing |" + " |" * 10)
                continue
            for mapping in ("inline", "thread"):
                print(_row(name, path, mapping, args.out))
                sys.stdout.flush()


if __name__ == "__main__":
    main()
