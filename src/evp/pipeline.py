"""One pipeline: a dataset's frames through an estimator into a trajectory, metrics and plots.

The CLI (``evp run``) drives it offline; the base station will drive the same estimator live.
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable, Iterable, Iterator
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import cv2
import numpy as np

from evp.config import Settings, write_settings
from evp.errors import DatasetError, EvaluationError, EvpError
from evp.estimator import Estimator, Refining, SelfCalibrating
from evp.io.dataset import Dataset
from evp.io.trajectory import Trajectory, write_trajectory
from evp.types import Frame, PoseEstimate, TrackingState

if TYPE_CHECKING:
    from evp.slam.system import SlamSystem

TRACKED_STATES = (TrackingState.OK, TrackingState.RELOCALIZED)


@dataclass
class RunResult:
    estimates: list[PoseEstimate] = field(default_factory=list)
    tracking_ms: list[float] = field(default_factory=list)
    skipped: list[str] = field(default_factory=list)  # why frames were not used
    dropped: list[int] = field(default_factory=list)  # frames a real-time replay had no time for
    reference_orb_ms: list[float] = field(default_factory=list)  # OpenCV ORB on the same frames
    slam: SlamSystem | None = None  # the engine, when the estimator builds a map
    refiner: Refining | None = None  # the estimator, when it can refine its trajectory at the end

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
        """Index (among fed frames) of the first frame answered with a pose."""
        return next((i for i, e in enumerate(self.estimates) if e.tracking_state in TRACKED_STATES), None)

    def final_trajectory(self) -> Trajectory:
        """The estimator's refined trajectory when it offers one (SLAM through the final
        bundle-adjusted keyframes, a photo survey adjusted as a whole); else the live one."""
        if self.refiner is None:
            return self.trajectory()
        stamps, poses = self.refiner.refined_trajectory()
        return Trajectory.from_poses(poses, stamps, "estimate")


def run_dataset(
    dataset: Dataset,
    estimator: Estimator,
    progress: Callable[[int], None] | None = None,
    reference_orb_features: int | None = None,
    realtime_speed: float | None = None,
) -> RunResult:
    """Feed every frame; undecodable or rejected frames are skipped and reported, never fatal.

    With ``reference_orb_features``, OpenCV's own ORB (that many features) is timed on each frame
    too, outside the tracking time, so that speed can be reported as a ratio measured in one run.
    With ``realtime_speed``, frames arrive at their recorded pace times that factor and the
    estimator always gets the newest one, as on the base station: frames that arrive while it is
    busy are dropped (``RunResult.dropped``).
    """
    from evp.slam.system import SlamSystem

    result = RunResult(slam=estimator if isinstance(estimator, SlamSystem) else None, refiner=estimator if isinstance(estimator, Refining) else None)
    reference_orb = cv2.ORB_create(reference_orb_features) if reference_orb_features else None
    errors: list[DatasetError] = []
    frames = dataset.frames(errors)
    if realtime_speed is not None:

        def drop(frame: Frame) -> None:
            result.dropped.append(frame.index)
            if progress:
                progress(1)

        frames = paced_frames(frames, realtime_speed, drop)
    last_stamp = -np.inf
    for frame in frames:
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
                if reference_orb is not None:
                    result.reference_orb_ms.append(_time_reference_orb(reference_orb, frame.image))
        if progress:
            progress(1)
    if result.slam is not None:
        result.slam.finish()
    result.skipped += [str(e) for e in errors]
    return result


def paced_frames(
    frames: Iterable[Frame],
    speed: float,
    on_drop: Callable[[Frame], None],
    clock: Callable[[], float] = time.perf_counter,
    sleep: Callable[[float], None] = time.sleep,
) -> Iterator[Frame]:
    """``frames`` released at their recorded pace (times ``speed``); each request gets the newest
    released frame, and a frame overtaken by a newer one before it was requested goes to
    ``on_drop``. A frame whose stamp does not increase is passed on at once (the caller rejects it)."""
    if speed <= 0:
        raise ValueError(f"real-time speed must be positive, not {speed}")
    waiting: Frame | None = None
    start_wall = start_stamp = 0.0
    for frame in frames:
        if waiting is None:
            start_wall, start_stamp = clock(), frame.timestamp
        elif frame.timestamp <= waiting.timestamp:
            yield frame
            continue
        release = start_wall + (frame.timestamp - start_stamp) / speed
        if waiting is not None:
            if clock() < release:
                yield waiting
            else:
                on_drop(waiting)
        sleep(max(0.0, release - clock()))
        waiting = frame
    if waiting is not None:
        yield waiting


def _time_reference_orb(orb: cv2.ORB, image: np.ndarray) -> float:
    grey = image if image.ndim == 2 else cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
    start = time.perf_counter()
    orb.detectAndCompute(grey, None)
    return (time.perf_counter() - start) * 1000.0


def _timing(result: RunResult) -> dict:
    def stats(values: list[float]) -> dict:
        array = np.array(values) if values else np.zeros(1)
        return {"median": float(np.median(array)), "p95": float(np.percentile(array, 95))}

    # SLAM: tracking time without the keyframe mapping a call may run first (inline mapping)
    tracking = result.slam.tracking_ms if result.slam is not None else result.tracking_ms
    tracking_stats = stats(tracking)
    timing: dict = {"tracking_ms": tracking, "tracking_ms_median": tracking_stats["median"], "tracking_ms_p95": tracking_stats["p95"]}
    if result.reference_orb_ms:
        timing["opencv_orb_ms"] = result.reference_orb_ms
        timing["opencv_orb_ms_median"] = stats(result.reference_orb_ms)["median"]
        timing["tracking_to_orb_ratio"] = timing["tracking_ms_median"] / max(timing["opencv_orb_ms_median"], 1e-9)
    if result.slam is not None:
        timing["orb_extraction_ms"] = result.slam.extraction_ms
        timing["mapping_ms_per_keyframe"] = result.slam.mapping_ms
        timing["mapping_ms_median"] = stats(result.slam.mapping_ms)["median"]
        timing["keyframe_queue_max"] = result.slam.mapping.max_queue
    return timing


def write_outputs(result: RunResult, dataset: Dataset, settings: Settings, out: Path) -> dict:
    """trajectory.tum, states.csv, timing.json, metrics.json (+ plots) when ground truth exists,
    settings.yaml; trajectory_live.tum (the poses as answered live) when trajectory.tum holds a
    refined trajectory; camera_estimated.yaml (usable as camera.calibration_file) when the
    estimator estimated the lens; for SLAM also keyframes.tum, map.ply and map.npz."""
    out.mkdir(parents=True, exist_ok=True)
    write_settings(settings, out)
    trajectory = result.final_trajectory()
    write_trajectory(out / "trajectory.tum", trajectory)
    if result.refiner is not None:
        write_trajectory(out / "trajectory_live.tum", result.trajectory())
    if isinstance(result.refiner, SelfCalibrating) and result.refiner.lens is not None:
        from evp.calib.camera_files import write_opencv_yaml

        write_opencv_yaml(out / "camera_estimated.yaml", result.refiner.lens, text={"estimated_by": type(result.refiner).__name__})
    if result.slam is not None:
        stamps, poses = result.slam.keyframe_trajectory()
        write_trajectory(out / "keyframes.tum", Trajectory.from_poses(poses, stamps, "keyframes"))
        result.slam.map.write_ply(out / "map.ply")
        result.slam.map.save(out / "map.npz")
    with (out / "states.csv").open("w") as handle:
        handle.write("timestamp,state,quality\n")
        for e in result.estimates:
            handle.write(f"{e.timestamp!r},{e.tracking_state.value},{e.quality}\n")
    (out / "timing.json").write_text(json.dumps(_timing(result), indent=2))
    metrics: dict = {
        "frames": dataset.num_frames,
        "frames_fed": len(result.estimates),
        "frames_dropped": len(result.dropped),
        "tracked_frames": len(trajectory),
        "tracked_fraction": len(trajectory) / max(1, dataset.num_frames),
        "tracked_live_frames": len(result.tracked),  # answered with a pose as they came (SLAM's start back-filled later is not)
        "init_frame": result.init_frame,
        "skipped": result.skipped,
    }
    if result.slam is not None:
        metrics["loop_closures"] = [asdict(closure) for closure in result.slam.loop_closures]
    if dataset.ground_truth is not None and len(trajectory) >= 3:
        from evp.eval.evaluate import evaluate
        from evp.eval.report import write_report

        try:
            evaluation = evaluate(dataset.ground_truth, trajectory, settings.eval)  # settings resolved for the dataset (resolve_settings)
        except EvaluationError as exc:
            metrics["evaluation_error"] = str(exc)
        else:
            metrics.update(evaluation.summary())
            write_report(evaluation, out / "plots", "ground truth", "trajectory.tum")
    (out / "metrics.json").write_text(json.dumps(metrics, indent=2))
    return metrics
