"""`evp run` on every shared image sequence with ground truth: one Markdown table.

Usage: python bench/run_sequences.py [--out runs/bench]
"""

from __future__ import annotations

import argparse
import platform
import resource
import sys
from pathlib import Path

import numpy as np

from evp.config import Settings
from evp.io.registry import open_dataset
from evp.pipeline import run_dataset, write_outputs
from evp.run_setup import camera_for, make_estimator

SHARED = Path(__file__).resolve().parents[2] / "shared" / "data"
SEQUENCES = ["euroc_mh_01_easy_moving_360", "kitti_odom_06_f000-050", "davis_slider_depth", "aerial_nadir_odm_toledo_fc350"]


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--out", type=Path, default=Path("runs/bench"))
    args = parser.parse_args()
    settings = Settings()
    print(f"command: python bench/run_sequences.py --out {args.out}  ({platform.node()}, {platform.processor() or platform.machine()})\n")
    print("| sequence | frames | tracked | first tracked frame | ATE Sim3 (m) | ATE / path | ms/frame median | ms/frame p95 |")
    print("|---|---|---|---|---|---|---|---|")
    for name in SEQUENCES:
        path = SHARED / name
        if not path.exists():
            print(f"| {name} | missing | | | | | | |")
            continue
        dataset = open_dataset(path)
        result = run_dataset(dataset, make_estimator(camera_for(dataset, settings), settings))
        metrics = write_outputs(result, dataset, settings, args.out / name)
        ms = np.array(result.tracking_ms)
        ate = f"{metrics['rmse']:.4f}" if "rmse" in metrics else "n/a"
        ratio = f"{100 * metrics['rmse'] / metrics['reference_path_length_m']:.2f} %" if "rmse" in metrics else "n/a"
        print(
            f"| {name} | {metrics['frames']} | {100 * metrics['tracked_fraction']:.1f} % | {metrics['init_frame']} | {ate} | {ratio} | {np.median(ms):.1f} | {np.percentile(ms, 95):.1f} |"
        )
        sys.stdout.flush()
    print(f"\npeak memory {resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024:.0f} MB")


if __name__ == "__main__":
    main()
