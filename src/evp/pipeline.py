"""One pipeline: frames from a source, through an estimator and stages, into sinks.

Every entry point drives it: ``evp run`` and the benches (a dataset, as fast as possible or in
real time), the station's per-session estimator process (live frames, newest first), ``evp
replay`` (a recorded session) and the tests. Nothing else feeds an estimator. The pipeline is
synchronous; where frames come from another thread or process, the runtime feeds its source.

Pacing policies:
- as fast as possible (offline runs): every frame, one after the other;
- real time (:class:`RealTime`): frames released at their recorded pace, the estimator always
  gets the newest one, frames overtaken while it was busy are dropped, as on the base station;
- live: the source itself only ever offers the newest frame (the runtime's estimator process
  keeps one waiting slot), so the pipeline takes them as they come.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass, field
from typing import Protocol

import cv2
import numpy as np

from evp.errors import EvpError, UsageError
from evp.estimator import Estimator
from evp.io.dataset import Dataset, TelemetryRecord
from evp.types import Frame, PoseEstimate, Trajectory
from evp.vision.images import to_grey


class Stage(Protocol):
    """A step after the estimator (a navigation filter...): an estimate in, an estimate out.
    ``observe`` gets every telemetry record (IMU, barometer, GPS...) in time order, each before
    the first frame not older than it; a stage that needs none leaves it a no-op."""

    def observe(self, record: TelemetryRecord) -> None:
        return None

    def process(self, frame: Frame, estimate: PoseEstimate) -> PoseEstimate: ...

    def predict(self, timestamp: float, pending: Sequence[TelemetryRecord] = ()) -> PoseEstimate | None:
        """The stage's own estimate at ``timestamp`` without a new estimate from the estimator (a
        navigation filter's IMU-propagated state), ``pending`` the telemetry not yet observed
        (held back for the estimator); None when it has none."""
        return None


class Sink:
    """Where the pipeline's results go (a recorder, files, a socket back to the vehicle, a
    progress bar). Each method has a no-op default; a sink overrides what it uses."""

    def on_estimate(self, frame: Frame, estimate: PoseEstimate, elapsed_ms: float) -> None:
        """A frame's answer, after the stages; ``elapsed_ms`` is the estimator's time on it."""

    def on_thread_time(self, frame: Frame, cpu_ms: float) -> None:
        """Before :meth:`on_estimate`: the CPU time the estimator spent on the frame in the
        pipeline's thread (work it hands to other threads is not in it). Steadier than
        ``elapsed_ms`` on a loaded machine, where the wall clock also counts other processes."""

    def on_skip(self, frame: Frame | None, reason: str) -> None:
        """A frame the estimator could not use (undecodable, rejected, time going backwards)."""

    def on_drop(self, frame: Frame) -> None:
        """A frame the pacing had no time for (real time: overtaken by a newer one)."""

    def on_finish(self, estimator: Estimator) -> None:
        """The stream ended and the estimator finished its work."""


class Pacing(Protocol):
    def __call__(self, frames: Iterable[Frame], on_drop: Callable[[Frame], None]) -> Iterable[Frame]: ...


def as_fast_as_possible(frames: Iterable[Frame], on_drop: Callable[[Frame], None]) -> Iterable[Frame]:
    """Every frame, as soon as the estimator is ready for it (offline runs; live sources that
    already hand over only the newest frame)."""
    return frames


@dataclass(frozen=True)
class RealTime:
    """Frames at their recorded pace times ``speed``, newest first (see :func:`paced_frames`)."""

    speed: float = 1.0
    clock: Callable[[], float] = time.perf_counter
    sleep: Callable[[float], None] = time.sleep

    def __call__(self, frames: Iterable[Frame], on_drop: Callable[[Frame], None]) -> Iterator[Frame]:
        return paced_frames(frames, self.speed, on_drop, self.clock, self.sleep)


class Pipeline:
    """source -> estimator -> stages -> sinks, with a pacing policy."""

    def __init__(self, estimator: Estimator, sinks: Sequence[Sink] = (), stages: Sequence[Stage] = (), pacing: Pacing = as_fast_as_possible):
        self.estimator = estimator
        self.sinks = list(sinks)
        self.stages = list(stages)
        self.pacing = pacing
        self._last_stamp = -np.inf

    def run(self, frames: Iterable[Frame], telemetry: Iterable[TelemetryRecord] = ()) -> None:
        """Feed every frame the pacing releases, each after the ``telemetry`` records (time order)
        stamped up to it, then finish the estimator; a run that fails part way (a bug, an
        interrupt) closes it, so no thread or process it started outlives the run. Telemetry is
        never dropped by the pacing; records after the last frame answer no frame and are not fed."""
        records = iter(telemetry)
        pending = next(records, None)
        try:
            for frame in self.pacing(frames, self._drop):
                while pending is not None and pending.timestamp <= frame.timestamp:
                    self.telemetry(pending)
                    pending = next(records, None)
                self.process(frame)
        except BaseException:
            self.estimator.close()
            raise
        self.finish()

    def process(self, frame: Frame) -> PoseEstimate | None:
        """One frame through the estimator, the stages and the sinks; a frame the estimator
        rejects (``EvpError``) or whose time does not increase is skipped and reported, never fatal.
        The estimator settles (maps the frame's keyframe) after the sinks have the answer."""
        if frame.timestamp <= self._last_stamp:
            self.skip(frame, f"frame {frame.index}: timestamp {frame.timestamp!r} does not increase")
            return None
        start, cpu_start = time.perf_counter(), time.thread_time()
        try:
            estimate = self.estimator.feed(frame)
        except EvpError as exc:
            self.skip(frame, str(exc))
            return None
        elapsed_ms = (time.perf_counter() - start) * 1000.0
        cpu_ms = (time.thread_time() - cpu_start) * 1000.0
        self._last_stamp = frame.timestamp
        for stage in self.stages:
            estimate = stage.process(frame, estimate)
        for sink in self.sinks:
            sink.on_thread_time(frame, cpu_ms)
            sink.on_estimate(frame, estimate, elapsed_ms)
        self.estimator.settle()
        return estimate

    def predict(self, timestamp: float, pending: Sequence[TelemetryRecord] = ()) -> PoseEstimate | None:
        """The answer for a frame at ``timestamp`` before (or without) the estimator: the last
        stage's that has one, given the telemetry not yet observed (``pending``). Live, each frame
        gets it at once while the estimator works on the newest frame it can take (see
        ``evp.runtime.live_pipeline``)."""
        for stage in reversed(self.stages):
            predict = getattr(stage, "predict", None)
            estimate = predict(timestamp, pending) if predict is not None else None
            if estimate is not None:
                return estimate
        return None

    def telemetry(self, record: TelemetryRecord) -> None:
        """One telemetry record (as it arrives live, or in time order from a dataset) to the
        estimator (an EKF-SLAM predicts with the wheels) and the stages."""
        self.estimator.observe(record)
        for stage in self.stages:
            stage.observe(record)

    def skip(self, frame: Frame | None, reason: str) -> None:
        """Report a frame the source or the estimator could not use."""
        for sink in self.sinks:
            sink.on_skip(frame, reason)

    def finish(self) -> None:
        self.estimator.finish()
        for sink in self.sinks:
            sink.on_finish(self.estimator)

    def _drop(self, frame: Frame) -> None:
        for sink in self.sinks:
            sink.on_drop(frame)


@dataclass
class RunResult(Sink):
    """A sink that keeps everything a run answered, for the files, metrics and plots after it."""

    estimator: Estimator
    estimates: list[PoseEstimate] = field(default_factory=list)
    tracking_ms: list[float] = field(default_factory=list)  # the estimator's time per frame, as the pipeline measured it
    feed_cpu_ms: list[float] = field(default_factory=list)  # its thread CPU time per frame (Sink.on_thread_time)
    skipped: list[str] = field(default_factory=list)  # why frames were not used
    dropped: list[int] = field(default_factory=list)  # frames a real-time replay had no time for
    reference_orb_ms: list[float] = field(default_factory=list)  # OpenCV's ORB on the same frames, when timed
    reference_orb_cpu_ms: list[float] = field(default_factory=list)  # and its thread CPU time
    refined: Trajectory | None = field(default=None, init=False)  # the estimator's refined trajectory, once asked
    _refinement_asked: bool = field(default=False, init=False, repr=False)

    def on_estimate(self, frame: Frame, estimate: PoseEstimate, elapsed_ms: float) -> None:
        self.estimates.append(estimate)
        self.tracking_ms.append(elapsed_ms)

    def on_thread_time(self, frame: Frame, cpu_ms: float) -> None:
        self.feed_cpu_ms.append(cpu_ms)

    def on_skip(self, frame: Frame | None, reason: str) -> None:
        self.skipped.append(reason)

    def on_drop(self, frame: Frame) -> None:
        self.dropped.append(frame.index)

    @property
    def tracked(self) -> list[PoseEstimate]:
        return [e for e in self.estimates if e.tracking_state.tracked]

    def trajectory(self) -> Trajectory:
        """The estimator's own poses as answered (its frame and scale, before any stage)."""
        tracked = self.tracked
        poses = np.array([e.visual_pose for e in tracked]).reshape(-1, 4, 4)
        return Trajectory.from_poses(poses, np.array([e.timestamp for e in tracked]), "estimate")

    def metric_trajectory(self) -> Trajectory:
        """The poses a navigation stage made metric and gravity-aligned (empty without one)."""
        metric = [e for e in self.tracked if e.metric]
        poses = np.array([e.T_world_cam for e in metric]).reshape(-1, 4, 4)
        return Trajectory.from_poses(poses, np.array([e.timestamp for e in metric]), "navigation")

    def segments(self) -> list[Trajectory]:
        """The tracked poses split where tracking was lost: a light VO restarts in a new frame and
        scale after a loss, so each piece is its own visual frame."""
        pieces: list[list[PoseEstimate]] = [[]]
        for estimate in self.estimates:
            if estimate.tracking_state.tracked:
                pieces[-1].append(estimate)
            elif pieces[-1]:
                pieces.append([])
        return [
            Trajectory.from_poses(np.array([e.visual_pose for e in piece]), np.array([e.timestamp for e in piece]), f"segment{k}")
            for k, piece in enumerate(p for p in pieces if p)
        ]

    @property
    def init_frame(self) -> int | None:
        """Index (among fed frames) of the first frame answered with a pose."""
        return next((i for i, e in enumerate(self.estimates) if e.tracking_state.tracked), None)

    def final_trajectory(self) -> Trajectory:
        """The estimator's refined trajectory when it offers one (SLAM through the final
        bundle-adjusted keyframes, a photo survey adjusted as a whole); else the live one. The
        estimator is asked once (SLAM's first answer adjusts the whole map); ``refined`` keeps it."""
        if not self._refinement_asked:
            self._refinement_asked = True
            answer = self.estimator.refined_trajectory()
            self.refined = None if answer is None else Trajectory.from_poses(answer[1], answer[0], "estimate")
        return self.trajectory() if self.refined is None else self.refined


class Progress(Sink):
    """Calls ``advance(1)`` for every frame the pipeline is done with (answered, skipped or dropped)."""

    def __init__(self, advance: Callable[[int], None]):
        self.advance = advance

    def on_estimate(self, frame: Frame, estimate: PoseEstimate, elapsed_ms: float) -> None:
        self.advance(1)

    def on_skip(self, frame: Frame | None, reason: str) -> None:
        if frame is not None:
            self.advance(1)

    def on_drop(self, frame: Frame) -> None:
        self.advance(1)


class ReferenceOrbTimer(Sink):
    """Times OpenCV's own ORB (same feature count) on each answered frame, outside the
    estimator's time, so that speed can be reported as a ratio measured in one run."""

    def __init__(self, features: int):
        self._orb = cv2.ORB_create(features)
        self.ms: list[float] = []
        self.cpu_ms: list[float] = []  # thread CPU time, as Sink.on_thread_time

    def on_estimate(self, frame: Frame, estimate: PoseEstimate, elapsed_ms: float) -> None:
        grey = to_grey(frame.image)
        start, cpu_start = time.perf_counter(), time.thread_time()
        self._orb.detectAndCompute(grey, None)
        self.ms.append((time.perf_counter() - start) * 1000.0)
        self.cpu_ms.append((time.thread_time() - cpu_start) * 1000.0)


def run_frames(
    estimator: Estimator,
    frames: Iterable[Frame],
    sinks: Sequence[Sink] = (),
    pacing: Pacing = as_fast_as_possible,
    stages: Sequence[Stage] = (),
    telemetry: Iterable[TelemetryRecord] = (),
) -> RunResult:
    """Frames already in hand (a test's, a bench's trial) through the pipeline, with ``telemetry``
    (time order) for the ``stages``; the recorded answers."""
    result = RunResult(estimator)
    Pipeline(estimator, [result, *sinks], stages, pacing).run(frames, telemetry)
    return result


def run_dataset(
    dataset: Dataset,
    estimator: Estimator,
    progress: Callable[[int], None] | None = None,
    reference_orb_features: int | None = None,
    realtime_speed: float | None = None,
    sinks: Sequence[Sink] = (),
    stages: Sequence[Stage] = (),
) -> RunResult:
    """A dataset through the pipeline: every frame as fast as possible, or with
    ``realtime_speed`` at its recorded pace times that factor, newest first (``RunResult.dropped``).
    Undecodable or rejected frames are skipped and reported, never fatal. With
    ``reference_orb_features`` OpenCV's ORB is timed on each frame too (``RunResult.reference_orb_ms``).
    The dataset's telemetry goes to the estimator and the ``stages`` too, each record before the
    frames not older than it (the order of :meth:`Dataset.stream`, a record stamped as a frame first)."""
    timer = ReferenceOrbTimer(reference_orb_features) if reference_orb_features else None
    extra: list[Sink] = [*sinks, *([timer] if timer else []), *([Progress(progress)] if progress else [])]
    errors: list[EvpError] = []  # frames the reader could not decode, in the order met
    pacing = as_fast_as_possible if realtime_speed is None else RealTime(realtime_speed)
    result = run_frames(estimator, dataset.frames(errors), extra, pacing, stages, dataset.telemetry())
    result.skipped += [str(error) for error in errors]
    result.reference_orb_ms = timer.ms if timer is not None else []
    result.reference_orb_cpu_ms = timer.cpu_ms if timer is not None else []
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
        raise UsageError(f"real-time speed must be positive, not {speed}")
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
