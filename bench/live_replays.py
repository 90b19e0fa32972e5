"""The circle replayed live, again and again: frames arrive at 30 fps, tracking drops what it has
no time for, and mapping runs in its thread, as `evp run --realtime` and the base station do.
Thread timing never repeats, so a rare drift shows only as a share of many replays; this counts
it (bench/mapping_lag.py replays a drawn lag exactly, but has not reproduced this drift).

Usage: python bench/live_replays.py [--trials 16] [--dataset FOLDER] [--contend] [--set SECTION.KEY=VALUE ...]

``--contend`` keeps one core busy with another process during the replays, as a second job on a
two-core base station would: the regime where frames are dropped by the hundred.

Per replay: poses answered live, frames dropped, keyframes at the end, ATE (Sim3) of the live
poses, and the largest rotation error since the camera starts moving (as bench/mapping_lag.py);
a replay whose rotation error passed 15 degrees drifted. Takes the sequence's length per replay
plus a few seconds.
"""

from __future__ import annotations

import argparse
import multiprocessing
import platform
import tempfile
from contextlib import contextmanager
from pathlib import Path

from mapping_lag import drift_of_final_map_poses, print_drift_table
from run_sequences import render_circle, settings_with_changes

from evp.io.registry import open_dataset
from evp.pipeline import run_dataset
from evp.run_setup import camera_for, make_estimator


def _replay(dataset, settings) -> tuple[int, int, int, float, float]:
    estimator = make_estimator(camera_for(dataset, settings), settings, dataset)
    result = run_dataset(dataset, estimator, realtime_speed=1.0)
    answered, ate, drift = drift_of_final_map_poses(dataset, result.estimates)
    return answered, len(result.dropped), len(estimator.map.keyframes), ate, drift


def _spin() -> None:
    while True:
        pass


@contextmanager
def _competing_process(enabled: bool):
    """A process that keeps one core busy while the replays run (nothing when not enabled)."""
    if not enabled:
        yield
        return
    competitor = multiprocessing.Process(target=_spin, daemon=True)
    competitor.start()
    try:
        yield
    finally:
        competitor.terminate()
        competitor.join()


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--trials", type=int, default=16)
    parser.add_argument("--dataset", type=Path, help="a sequence with ground truth (default: render the circle as bench/run_sequences.py does, seed 1)")
    parser.add_argument("--contend", action="store_true", help="keep one core busy with another process meanwhile")
    parser.add_argument("--set", nargs="+", default=[], metavar="SECTION.KEY=VALUE", help="settings to change, e.g. slam.new_point_min_parallax_deg=1.1")
    args = parser.parse_args()
    settings = settings_with_changes("slam", ["slam.mapping=thread", *args.set])
    dataset_arg = f" --dataset {args.dataset}" if args.dataset else ""
    changed = (" --contend" if args.contend else "") + (f" --set {' '.join(args.set)}" if args.set else "")
    print(f"command: python bench/live_replays.py --trials {args.trials}{dataset_arg}{changed}  ({platform.node()}, {platform.machine()})\n")
    with tempfile.TemporaryDirectory() as tmp:
        dataset = open_dataset(args.dataset or render_circle(Path(tmp) / "circle"))

        def replays():
            for trial in range(1, args.trials + 1):
                with _competing_process(args.contend):
                    answered, dropped, keyframes, ate, drift = _replay(dataset, settings)
                yield [str(trial), f"{answered}/{dataset.num_frames}", str(dropped), str(keyframes)], ate, drift

        print_drift_table(["replay", "answered live", "dropped", "keyframes at the end"], replays(), "replays")


if __name__ == "__main__":
    main()
