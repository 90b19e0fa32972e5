"""How often the live circle drifts: the rendered circle (or a sequence) replayed live again and
again, frames at 30 fps, tracking dropping what it has no time for and mapping in its thread, as
`evp run --realtime` and the base station do.

Thread timing never repeats, so a rare drift shows only as a share of many replays; this counts
it. `--contend` keeps one core busy with another process during each replay (a second job on a
two-core base station): the regime where frames are dropped by the hundred.

Usage: python bench/live_replays.py [--trials 16] [--dataset FOLDER] [--contend] [--set SECTION.KEY=VALUE ...]

Prints per replay: poses answered live, frames dropped, keyframes at the end, ATE (Sim3) of the
live poses and the largest rotation error since the camera starts moving (as
bench/mapping_lag.py); then how many replays drifted (rotation error over 15 degrees) and the
spreads, which is what is recorded. Needs no shared data (renders the circle); takes the
sequence's length per replay plus a few seconds.
"""

from __future__ import annotations

import argparse
import multiprocessing
import platform
import tempfile
from contextlib import contextmanager
from pathlib import Path

from mapping_lag import DRIFT_COLUMNS, drift_of_final_map_poses, print_drift_table
from results import Results
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
    command = f"python bench/live_replays.py --trials {args.trials}{dataset_arg}{changed}"
    print(f"command: {command}  ({platform.node()}, {platform.machine()})\n")
    with tempfile.TemporaryDirectory() as tmp:
        dataset = open_dataset(args.dataset or render_circle(Path(tmp) / "circle"))

        def replays():
            for trial in range(1, args.trials + 1):
                with _competing_process(args.contend):
                    answered, dropped, keyframes, ate, drift = _replay(dataset, settings)
                yield [str(trial), f"{answered}/{dataset.num_frames}", str(dropped), str(keyframes)], ate, drift

        summary = print_drift_table(["replay", "answered live", "dropped", "keyframes at the end"], replays(), "replays")
    columns = [DRIFT_COLUMNS[0], ("another process on a core", "{contend}"), *DRIFT_COLUMNS[1:]]
    table = Results("live_replays", command).table("replays", columns, key=["dataset", "contend", "changes"], caption="Live replays, drift over all replays")
    table.add(
        {"dataset": args.dataset.name if args.dataset else "circle", "contend": "yes" if args.contend else "no", "changes": " ".join(args.set), **summary}
    )


if __name__ == "__main__":
    main()
