"""SLAM on a stream that drops frames, as the base station's link does when the estimator is busy
(at most one frame waits; a newer one replaces it).

The sequence is fed with every 2nd, 3rd and 4th frame (each offset) and, per seed, twice in a row
keeping each frame with the given probability (the second pass starts over: a jump back to the
start that relocalisation must catch).

Usage: python bench/dropped_frames.py [--sequence PATH] [--keep 0.5 0.3] [--seeds 6]
       python bench/dropped_frames.py --shared [--seeds 2]

Prints per pattern the share of the fed frames answered with tracking state OK, and the mean.
Needs no shared data (default: the bundled sample). `--shared` runs issue 29's check instead: each
shared video sequence (../shared/data) once through with 20 % of its frames dropped at random,
per seed: the share of the fed frames in the refined trajectory (trajectory.tum; target 95 %)
and answered OK live.
"""

from __future__ import annotations

import argparse
import platform
from pathlib import Path

import numpy as np
from results import Results

from evp.config import Settings
from evp.io.registry import open_dataset
from evp.pipeline import run_frames
from evp.run_setup import make_estimator
from evp.types import Frame, TrackingState

SAMPLE = Path(__file__).resolve().parents[1] / "data" / "sample" / "davis_slider_depth"
SHARED = Path(__file__).resolve().parents[2] / "shared" / "data"
SHARED_VIDEO = ["euroc_mh_01_easy_moving_360", "kitti_odom_06_f000-050", "davis_slider_depth"]


def _ok_share(dataset, frames: list[Frame]) -> float:
    estimator = make_estimator(dataset.camera, Settings(estimator="slam"))
    states = [estimate.tracking_state for estimate in run_frames(estimator, frames).estimates]
    return sum(s == TrackingState.OK for s in states) / max(1, len(states))


def _random_drops(frames: list[Frame], keep: float, seed: int) -> list[Frame]:
    rng = np.random.default_rng(seed)
    period = frames[-1].timestamp - frames[0].timestamp + (frames[1].timestamp - frames[0].timestamp)
    kept = []
    for repeat in range(2):
        for frame in frames:
            if rng.random() < keep:
                kept.append(Frame(frame.timestamp + repeat * period, frame.image, len(kept), frame.source))
    return kept


COLUMNS = [
    ("sequence", "{sequence}"),
    ("frames fed", "{pattern}"),
    ("patterns", "{patterns}"),
    ("OK share per pattern", "{shares_text}"),
    ("mean", "{mean_share:.2f}"),
]


def _record(sequence: str, pattern: str, patterns: str, shares: list[float]) -> dict:
    return {
        "sequence": sequence,
        "pattern": pattern,
        "patterns": patterns,
        "shares": shares,
        "shares_text": " ".join(f"{s:.2f}" for s in shares),
        "mean_share": float(np.mean(shares)),
    }


SHARED_COLUMNS = [
    ("sequence", "{sequence}"),
    ("frames dropped", "{pattern}"),
    ("seed", "{seed}"),
    ("fed", "{fed}"),
    ("in trajectory.tum", "{tracked_percent:.1f} %"),
    ("answered OK live", "{live_percent:.1f} %"),
    ("first pose (fed frame)", "{init_frame}"),
]


def _shared_random_drops(seeds: int) -> None:
    """Each shared video sequence with a fifth of its frames dropped at random, once through."""
    command = f"python bench/dropped_frames.py --shared --seeds {seeds}"
    print(f"command: {command}  ({platform.node()}, {platform.machine()})\n")
    table = Results("dropped_frames", command).table(
        "random_drops", SHARED_COLUMNS, key=["sequence", "seed"], caption="20 % of the frames dropped at random (issue 29: >= 95 % of the fed frames tracked)"
    )
    print(table.header())
    for sequence in SHARED_VIDEO:
        if not (SHARED / sequence).is_dir():
            print(f"{sequence}: not in {SHARED}, skipped")
            continue
        dataset = open_dataset(SHARED / sequence)
        every = list(dataset.frames())
        for seed in range(1, seeds + 1):
            rng = np.random.default_rng(seed)
            frames = [frame for frame in every if rng.random() >= 0.2]
            result = run_frames(make_estimator(dataset.camera, Settings(estimator="slam"), dataset), frames, telemetry=dataset.telemetry())  # its IMU too, as evp run
            record = {
                "sequence": sequence,
                "pattern": "20 % at random",
                "seed": seed,
                "fed": len(frames),
                "tracked_percent": 100.0 * len(result.final_trajectory()) / len(frames),
                "live_percent": 100.0 * len(result.tracked) / len(frames),
                "init_frame": result.init_frame,
            }
            print(table.add(record), flush=True)


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--sequence", type=Path, default=SAMPLE)
    parser.add_argument("--keep", type=float, nargs="+", default=[0.5, 0.3])
    parser.add_argument("--seeds", type=int, default=None, help="6 by default; 2 with --shared")
    parser.add_argument("--shared", action="store_true", help="20 %% random drops on each shared video sequence")
    args = parser.parse_args()
    if args.shared:
        _shared_random_drops(args.seeds or 2)
        return
    args.seeds = args.seeds or 6
    command = f"python bench/dropped_frames.py --sequence {args.sequence} --keep {' '.join(map(str, args.keep))} --seeds {args.seeds}"
    print(f"command: {command}  ({platform.node()}, {platform.machine()})\n")
    table = Results("dropped_frames", command).table("patterns", COLUMNS, key=["sequence", "pattern"], caption="Share of the fed frames answered OK")
    dataset = open_dataset(args.sequence)
    frames = list(dataset.frames())
    print(table.header())
    sequence = args.sequence.name
    for stride in (2, 3, 4):
        shares = [_ok_share(dataset, frames[offset::stride]) for offset in range(stride)]
        print(table.add(_record(sequence, f"every {stride}", f"{stride} offsets", shares)), flush=True)
    for keep in args.keep:
        shares = [_ok_share(dataset, _random_drops(frames, keep, seed)) for seed in range(1, args.seeds + 1)]
        print(table.add(_record(sequence, f"{100 * keep:.0f} % at random, twice", f"{args.seeds} seeds", shares)), flush=True)


if __name__ == "__main__":
    main()
