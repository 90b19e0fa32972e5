"""The live circle's drift reproduced without a clock: SLAM with mapping busy a random 100-233 ms
per keyframe, counted in frames at the sequence's rate (3-7 at 30 fps, as the mapping thread on
the live circle), so a drifting trial replays exactly.

Tracking inserts keyframes only while the mapper is free; a keyframe's new points reach tracking
at the next frame and its local bundle adjustment at the end of its lag, in the thread's order.
Each trial draws its lags from its seed, where a live replay's thread timing never repeats.

Usage: python bench/mapping_lag.py [--trials 30] [--seconds 8] [--dataset FOLDER] [--set SECTION.KEY=VALUE ...]

Prints per trial: keyframes, tracked frames, ATE (Sim3) of the poses answered in the map kept at
the end (a start that tracking discarded leaves its poses out, as `evp run` does) and the largest
rotation error since the camera starts moving (relative rotation from the first tracked frame
after 1.5 s, estimate against truth, so no alignment enters it); then how many trials drifted past
15 degrees and the spreads, which is what is recorded. Needs no shared data (renders the circle).
"""

from __future__ import annotations

import argparse
import platform
import tempfile
from collections.abc import Callable, Iterable
from pathlib import Path

import numpy as np
from results import Results
from run_sequences import render_circle, settings_with_changes
from scipy.spatial.transform import Rotation

from evp.config import EvalSettings, Settings
from evp.eval.evaluate import evaluate
from evp.io.registry import open_dataset
from evp.io.vocabulary_files import load_configured_vocabulary
from evp.pipeline import run_frames
from evp.slam.local_mapping import LocalMapper, NewKeyFrame
from evp.slam.scheduler import InlineScheduler
from evp.slam.system import SlamSystem
from evp.types import PoseEstimate, TrackingState, Trajectory

MOVING_AFTER_S = 1.5  # the rendered circle stands for 2 s
MAPPING_S = (0.100, 0.233)  # the mapping thread's time per keyframe on the live circle, this machine
DRIFT_DEG = 15.0


class LaggedMapping:
    """Mapping with :class:`InlineMapping`'s interface, busy for a random number of frames per
    keyframe, in the tracking thread (reproducible). As the thread does live, a keyframe's new
    points reach tracking at the next frame (the thread triangulates them in 20-60 ms) and its
    local bundle adjustment when the drawn frames have passed. The lag is counted in frames fed
    (``frames_fed``), since the engine settles its mapping both before a frame and, driven by the
    pipeline, after one."""

    def __init__(self, mapper: LocalMapper, seed: int, frames: tuple[int, int], frames_fed: Callable[[], int]):
        self.mapper = mapper
        self._frames_fed = frames_fed
        self._counted = 0  # frames fed when the lag last advanced
        self.mapping_ms: list[float] = []  # not timed: the drawn lag stands for the time
        self.max_queue = 0
        self._rng = np.random.default_rng(seed)
        self._frames = frames  # least and most frames per keyframe
        self._queue: list[NewKeyFrame] = []
        self._head_kept: bool | None = None  # the head's points triangulated (False: its map discarded); None: not yet
        self._frames_left = 0

    @property
    def idle(self) -> bool:
        return not self._queue

    @property
    def pending(self) -> int:
        return max(0, len(self._queue) - 1)

    def interrupt(self) -> None:
        """Nothing runs while tracking does."""

    def submit(self, item: NewKeyFrame) -> None:
        if not self._queue:
            self._frames_left = self._busy_frames()
        self._queue.append(item)

    def settle(self) -> None:
        if not self._queue or self._frames_fed() == self._counted:
            return
        self._counted = self._frames_fed()
        if self._head_kept is None:
            self._head_kept = self.mapper.insert(self._queue[0])
        self._frames_left -= 1
        if self._frames_left <= 0:
            item = self._queue.pop(0)
            if self._head_kept:
                self.mapper.refine(item)
            self._head_kept = None
            self._frames_left = self._busy_frames()

    def _busy_frames(self) -> int:
        return int(self._rng.integers(self._frames[0], self._frames[1] + 1))

    def finish(self) -> None:
        while self._queue:
            self._frames_left = 1  # due now
            self._counted = -1
            self.settle()


class LaggedScheduler(InlineScheduler):
    """The inline schedule with :class:`LaggedMapping` (``frames_fed`` set once the engine exists)."""

    def __init__(self, seed: int, frames: tuple[int, int]):
        self.seed, self.frames = seed, frames
        self.frames_fed: Callable[[], int] = lambda: 0

    def start_mapping(self, mapper: LocalMapper) -> LaggedMapping:
        return LaggedMapping(mapper, self.seed, self.frames, lambda: self.frames_fed())


def _busy_frames_range(frames) -> tuple[int, int]:
    rate = (len(frames) - 1) / (frames[-1].timestamp - frames[0].timestamp)
    least = max(1, round(MAPPING_S[0] * rate))
    return least, max(least, round(MAPPING_S[1] * rate))


def _trial(dataset, frames, seed: int, settings: Settings) -> tuple[int, int, float, float]:
    scheduler = LaggedScheduler(seed, _busy_frames_range(frames))
    slam = SlamSystem(dataset.camera, settings.orb, settings.slam, vocabulary=load_configured_vocabulary(settings.slam.vocabulary), scheduler=scheduler)
    scheduler.frames_fed = lambda: slam.frames_fed
    tracked, ate, drift = drift_of_final_map_poses(dataset, run_frames(slam, frames).estimates)
    return len(slam.map.keyframes), tracked, ate, drift


def drift_of_final_map_poses(dataset, estimates: list[PoseEstimate]) -> tuple[int, float, float]:
    """``(poses, ATE, largest rotation error)`` of the poses answered in the map kept at the end
    (a start that tracking discarded leaves its poses out, as `evp run` does). ATE is Sim3; the
    rotation error (degrees) is the relative rotation from the first pose after
    ``MOVING_AFTER_S``, estimate against truth, so no alignment enters it."""
    stamps, poses = [], []
    for estimate in estimates:
        if estimate.tracking_state == TrackingState.NOT_INITIALIZED:
            stamps, poses = [], []  # a start tracking discarded: its poses were in another frame
        elif estimate.tracking_state.tracked:
            stamps.append(estimate.timestamp)
            poses.append(estimate.T_world_cam)
    stamps, poses = np.array(stamps), np.array(poses)
    truth = dataset.ground_truth
    ate = evaluate(truth, Trajectory.from_poses(poses, stamps), EvalSettings(align="sim3", max_time_diff_s=0.01)).summary()["rmse"]
    true_rotations = Rotation.from_quat(truth.quats_xyzw[np.searchsorted(truth.timestamps, stamps - 1e-6)])
    estimated = Rotation.from_matrix(poses[:, :3, :3])
    first = min(int(np.searchsorted(stamps - dataset.frame_times[0], MOVING_AFTER_S)), len(stamps) - 1)  # a late start: its first frame
    error = (true_rotations[first].inv() * true_rotations).inv() * (estimated[first].inv() * estimated)
    return len(stamps), ate, float(np.degrees(error[first:].magnitude()).max())


DRIFT_COLUMNS = [
    ("dataset", "{dataset}"),
    ("settings changed", "{changes}"),
    ("drifted (rotation error over 15 deg)", "{drifted} of {trials}"),
    ("rotation error median / largest (deg)", "{rotation_error_median_deg:.1f} / {rotation_error_max_deg:.1f}"),
    ("ATE median (m)", "{ate_median_m:.4f}"),
]


def print_drift_table(columns: list[str], trials: Iterable[tuple[list[str], float, float]], runs: str) -> dict:
    """A table of trials, a row as each comes (its cells, then ATE and largest rotation error, the
    table's last two columns), and the line under it: how many drifted past ``DRIFT_DEG``, and the
    spreads. Returns that line's figures (a record for ``DRIFT_COLUMNS``)."""
    print(f"| {' | '.join(columns)} | ATE Sim3 (m) | largest rotation error (deg) |\n" + "|---" * (len(columns) + 2) + "|")
    drifts, ates = [], []
    for cells, ate, drift in trials:
        drifts.append(drift)
        ates.append(ate)
        print(f"| {' | '.join(cells)} | {ate:.4f} | {drift:.1f} |", flush=True)
    drifted = sum(d > DRIFT_DEG for d in drifts)
    print(
        f"\n{drifted} of {len(drifts)} {runs} drifted (rotation error over {DRIFT_DEG:g} deg); rotation error median {np.median(drifts):.1f}, "
        f"mean {np.mean(drifts):.1f}, largest {max(drifts):.1f} deg; ATE median {np.median(ates):.4f} m, mean {np.mean(ates):.4f} m"
    )
    return {
        "trials": len(drifts),
        "drifted": drifted,
        "rotation_error_median_deg": float(np.median(drifts)),
        "rotation_error_mean_deg": float(np.mean(drifts)),
        "rotation_error_max_deg": float(max(drifts)),
        "ate_median_m": float(np.median(ates)),
        "ate_mean_m": float(np.mean(ates)),
    }


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--trials", type=int, default=30)
    parser.add_argument("--seconds", type=float, default=8.0)
    parser.add_argument("--dataset", type=Path, help="a sequence with ground truth (default: render the circle as bench/run_sequences.py does, seed 1)")
    parser.add_argument("--set", nargs="+", default=[], metavar="SECTION.KEY=VALUE", help="settings to change, e.g. slam.init_min_parallax_deg=2")
    args = parser.parse_args()
    settings = settings_with_changes("slam", args.set)
    dataset_arg = f" --dataset {args.dataset}" if args.dataset else ""
    changed = f" --set {' '.join(args.set)}" if args.set else ""
    command = f"python bench/mapping_lag.py --trials {args.trials} --seconds {args.seconds:g}{dataset_arg}{changed}"
    print(f"command: {command}  ({platform.node()}, {platform.machine()})\n")
    with tempfile.TemporaryDirectory() as tmp:
        dataset = open_dataset(args.dataset or render_circle(Path(tmp) / "circle"))
        frames = [f for f in dataset.frames() if f.timestamp - dataset.frame_times[0] <= args.seconds]

        def trials():
            for seed in range(1, args.trials + 1):
                keyframes, tracked, ate, drift = _trial(dataset, frames, seed, settings)
                yield [str(seed), str(keyframes), f"{tracked}/{len(frames)}"], ate, drift

        summary = print_drift_table(["trial (seed)", "keyframes at the end", "tracked in the final map"], trials(), "trials")
    columns = [DRIFT_COLUMNS[0], ("seconds", "{seconds:g}"), *DRIFT_COLUMNS[1:]]
    table = Results("mapping_lag", command).table("trials", columns, key=["dataset", "seconds", "changes"], caption="Drawn mapping lags, drift over all trials")
    table.add({"dataset": args.dataset.name if args.dataset else "circle", "seconds": args.seconds, "changes": " ".join(args.set), **summary})


if __name__ == "__main__":
    main()
