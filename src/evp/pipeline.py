"""One pipeline: a dataset's frames through an estimator into a trajectory, metrics and plots.

The CLI (``evp run``) drives it offline; the base station will drive the same estimator live.
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from evp.config import Settings, write_settings
from evp.errors import DatasetError, EvaluationError, EvpError
from evp.estimator import Estimator
from evp.io.dataset import Dataset
from evp.io.trajectory import Trajectory, write_trajectory
from evp.types import PoseEstimate, TrackingState

TRACKED_STATES = (TrackingState.OK, TrackingState.RELOCALIZED)


@dataclass
class RunResult:
    estimates: list[PoseEstimate] = field(default_factory=list)
    tracking_ms: list[float] = field(default_factory=list)
    skipped: list[str] = field(default_factory=list)  # why frames were not used

    @property
    def tracked(self) -> list[PoseEstimate]:
        return [e for e in self.estimates if e.tracking_state in TRACKED_STATES]

    def trajectory(self) -> Trajectory:
        tracked = self.tracked
        poses = np.array([e.T_world_cam for e in tracked]).reshape(-1, 4, 4)
        return Trajectory.from_poses(poses, np.array([e.timestamp for e in tracked]), "estimate")

    def segments(self) -> list[Trajectory]:
        """The tracked poses split where tracking was lost: a light VO restarts in a new frame and
        scale after a loss, so each piece is its own visual frame."""
        pieces: list[list[PoseEstimate]] = [[]]
        for estimate in self.estimates:
            if estimate.tracking_state in TRACKED_STATES:
                pieces[-1].append(estimate)
            elif pieces[-1]:
                pieces.append([])
        return [
            Trajectory.from_poses(np.array([e.T_world_cam for e in piece]), np.array([e.timestamp for e in piece]), f"segment{k}")
            for k, piece in enumerate(p for p in pieces if p)
        ]

    @property
    def init_frame(self) -> int | None:
        """Index (among fed frames) of the first tracked frame."""
        return next((i for i, e in enumerate(self.estimates) if e.tracking_state in TRACKED_STATES), None)


def run_dataset(dataset: Dataset, estimator: Estimator, progress: Callable[[int], None] | None = None) -> RunResult:
    """Feed every frame; undecodable or rejected frames are skipped and reported, never fatal."""
    result = RunResult()
    errors: list[DatasetError] = []
    last_stamp = -np.inf
    for frame in dataset.frames(errors):
        if frame.timestamp <= last_stamp:
            result.skipped.append(f"frame {frame.index}: timestamp {frame.timestamp!r} does not increase")
        else:
            start = time.perf_counter()
            try:
                estimate = estimator.feed(frame)
            except EvpError as exc:
                result.skipped.append(str(exc))
            else:
                result.tracking_ms.append((time.perf_counter() - start) * 1000.0)
                result.estimates.append(estimate)
                last_stamp = frame.timestamp
        if progress:
            progress(1)
    result.skipped += [str(e) for e in errors]
    return result


def _max_time_difference(dataset: Dataset) -> float:
    """Half a frame period: each estimate matches at most its own ground-truth stamp."""
    if dataset.num_frames < 2:
        return 0.01
    return float(0.5 * np.median(np.diff(dataset.frame_times)))


def write_outputs(result: RunResult, dataset: Dataset, settings: Settings, out: Path) -> dict:
    """trajectory.tum, states.csv, timing.json, metrics.json (+ plots) when ground truth exists, settings.yaml."""
    out.mkdir(parents=True, exist_ok=True)
    write_settings(settings, out)
    trajectory = result.trajectory()
    write_trajectory(out / "trajectory.tum", trajectory)
    with (out / "states.csv").open("w") as handle:
        handle.write("timestamp,state,quality\n")
        for e in result.estimates:
            handle.write(f"{e.timestamp!r},{e.tracking_state.value},{e.quality}\n")
    ms = np.array(result.tracking_ms) if result.tracking_ms else np.zeros(1)
    (out / "timing.json").write_text(
        json.dumps(
            {
                "tracking_ms": result.tracking_ms,
                "tracking_ms_median": float(np.median(ms)),
                "tracking_ms_p95": float(np.percentile(ms, 95)),
            },
            indent=2,
        )
    )
    metrics: dict = {
        "frames": dataset.num_frames,
        "frames_fed": len(result.estimates),
        "tracked_frames": len(trajectory),
        "tracked_fraction": len(trajectory) / max(1, dataset.num_frames),
        "init_frame": result.init_frame,
        "skipped": result.skipped,
    }
    if dataset.ground_truth is not None and len(trajectory) >= 3:
        from evp.eval.evaluate import EvaluationOptions, evaluate
        from evp.eval.metrics import Alignment
        from evp.eval.report import write_report

        try:
            evaluation = evaluate(dataset.ground_truth, trajectory, EvaluationOptions(Alignment.SIM3, max_diff_s=_max_time_difference(dataset)))
        except EvaluationError as exc:
            metrics["evaluation_error"] = str(exc)
        else:
            metrics.update(evaluation.summary())
            write_report(evaluation, out / "plots", "ground truth", "trajectory.tum")
    (out / "metrics.json").write_text(json.dumps(metrics, indent=2))
    return metrics
