"""The one pipeline driven live: every frame answered at once, vision correcting when it is ready.

A vehicle needs a pose for every frame, now; SLAM takes 30-300 ms a frame on a small station and
more when it maps. So the caller's thread (the link: telemetry and frames as they arrive) and a
vision worker share the :class:`~evp.pipeline.Pipeline`:

- telemetry waits for vision (PX4's delayed horizon): the worker gives the stages the records up
  to a frame's time just before it runs the estimator on that frame, so the stages see
  telemetry and poses in time order, as offline; a record older than the newest by more than
  ``max_hold_s`` goes to the stages anyway (vision is stalled; the filter fuses the late pose
  through its own delayed horizon);
- a frame is answered at once with the stages' current estimate carried through the telemetry
  still held (:meth:`Pipeline.predict`: the filter's state propagated on the newest IMU
  samples), or, while no stage has one (no filter, or before it starts), the estimator's last
  answer carried to the frame's time; each answer says how old its last visual correction is;
- the worker runs the estimator on the newest frame it can take (a frame that arrives while it
  is busy replaces the one waiting).

The stages are pure and single-threaded; here each call into them holds one lock, so telemetry,
predictions and visual updates never interleave inside a stage. The estimator runs outside the
lock. The link's thread never waits long for it: a stage's call can take a while (the
visual-inertial start's refinement, up to ~0.2 s on two cores), and a link blocked that long lets
frames pile up and be dropped. Telemetry is held under a lock of its own and given to the stages
only when their lock is free; an answer waits at most ``ANSWER_WAIT_S`` for it, else it is the
previous answer's pose at the new time. ``at_once=False`` answers each frame by the pipeline's sinks after the estimator and the
stages (the caller bounds what is in flight).
"""

from __future__ import annotations

import threading
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass, replace

from evp.io.dataset import TelemetryRecord
from evp.pipeline import Pipeline, Sink
from evp.types import Frame, PoseEstimate

# The vision thread hands the held telemetry to the stages this many records at a time (the lock
# taken for each batch): 20 IMU steps of the filter take a few ms, so an answer waits no longer.
RELEASE_BATCH = 20
# An answer waits this long at most for the stages' lock: a visual update holds it ~2 ms, the
# visual-inertial start's solve up to ~200 ms; a frame period (33 ms) is the most a vehicle's
# answer may be late.
ANSWER_WAIT_S = 0.01


@dataclass(frozen=True)
class LiveAnswer:
    """What a frame is answered with at once: ``estimate`` None before the estimator has
    answered anything and no stage can predict; ``visual_age_s`` is the frame's time minus the
    last frame vision tracked (None before one); ``reset_counter`` counts every jump of the
    answered frame (the estimator's relocalisations and new maps, its loop corrections, a stage's
    change of frame)."""

    seq: int
    timestamp: float
    estimate: PoseEstimate | None
    visual_age_s: float | None
    reset_counter: int


class _LockedStage:
    """A stage whose calls hold the live pipeline's lock."""

    def __init__(self, stage, lock: threading.Lock):
        self.stage, self._lock = stage, lock

    def observe(self, record: TelemetryRecord) -> None:
        with self._lock:
            self.stage.observe(record)

    def process(self, frame: Frame, estimate: PoseEstimate) -> PoseEstimate:
        with self._lock:
            return self.stage.process(frame, estimate)

    def predict(self, timestamp: float, pending: Sequence[TelemetryRecord] = ()) -> PoseEstimate | None:
        predict = getattr(self.stage, "predict", None)
        if predict is None:
            return None
        with self._lock:
            return predict(timestamp, pending)


class _Latest(Sink):
    """The estimator's newest answer (after the stages), the newest tracked frame's time and the
    estimator's jumps so far (the first sink: the others see them up to date)."""

    def __init__(self, estimator):
        self.estimator = estimator
        self.estimate: PoseEstimate | None = None
        self.tracked_at: float | None = None
        self.jumps = estimator_jumps(estimator)

    def on_estimate(self, frame: Frame, estimate: PoseEstimate, elapsed_ms: float) -> None:
        self.estimate = estimate
        if estimate.tracking_state.tracked:
            self.tracked_at = estimate.timestamp
        self.jumps = estimator_jumps(self.estimator)


def estimator_jumps(estimator) -> int:
    """The estimator's discontinuities: its reset counter plus its loop corrections (a closed loop
    moves the map under the vehicle; SLAM's counter does not include them)."""
    return int(getattr(estimator, "reset_counter", 0)) + len(getattr(estimator, "loop_closures", ()))


class LivePipeline:
    """``telemetry(record)`` and ``frame(frame)`` from the link's thread; ``close()`` finishes the
    worker and the pipeline."""

    def __init__(self, pipeline: Pipeline, at_once: bool = True, max_hold_s: float = 1.0):
        self.pipeline = pipeline
        self.at_once = at_once
        self.max_hold_s = max_hold_s
        self._lock = threading.RLock()  # the stages' calls
        self._held_lock = threading.Lock()  # the telemetry held for them (taken after _lock, never before)
        self._held: deque[TelemetryRecord] = deque()
        self._last_answer: PoseEstimate | None = None
        self._stage_jumps = 0  # the stages' changes of frame at the last answer that could read them
        self._stages = list(pipeline.stages)
        pipeline.stages = [_LockedStage(stage, self._lock) for stage in self._stages]
        self._latest = _Latest(pipeline.estimator)
        pipeline.sinks.insert(0, self._latest)
        self._waiting: Frame | None = None
        # an estimator that takes telemetry itself (the EKF-SLAM's wheels, SLAM's gyro) must not
        # be given a record while it processes a frame, unless it keeps its calls in order itself
        # (one in the vision process or on a cluster): it then processes under the lock (answers
        # at once wait for its frame, ~20 ms for the EKF-SLAM); others run outside it
        estimator = pipeline.estimator
        self._feed_under_lock = estimator.uses_telemetry and not estimator.observes_while_feeding
        self._closing = False
        self._wake = threading.Condition()
        self.visual_frames = 0  # frames the estimator took
        self.failed: BaseException | None = None  # what ended vision (the estimator's process or worker lost, a bug)
        self._worker = threading.Thread(target=self._run, name="evp-vision", daemon=True)
        self._worker.start()

    @property
    def stages(self) -> list:
        """The stages themselves (read them under :meth:`locked`)."""
        return self._stages

    def locked(self):
        """The lock the stages' calls hold: read a stage's state (notices, GPS state) under it."""
        return self._lock

    def telemetry(self, record: TelemetryRecord) -> None:
        """Held for vision; what vision left waiting longer than ``max_hold_s`` goes on now, or
        with a later record when a stage is busy."""
        with self._held_lock:
            self._held.append(record)
        if self._lock.acquire(blocking=False):
            try:
                self._release(record.timestamp - self.max_hold_s)
            finally:
                self._lock.release()

    def _release(self, until: float, batch: int | None = None) -> bool:
        """The held records up to ``until`` to the stages (the lock held), at most ``batch`` of
        them; True when some are left."""
        count = 0
        while True:
            with self._held_lock:
                if not (self._held and self._held[0].timestamp <= until):
                    return False
                if batch is not None and count == batch:
                    return True
                record = self._held.popleft()
            self.pipeline.telemetry(record)
            count += 1

    def frame(self, frame: Frame) -> LiveAnswer | None:
        """Hand a frame to the estimator (newest first); with ``at_once`` its answer now, else
        None (the pipeline's sinks answer it)."""
        answer = self.answer(frame.index, frame.timestamp) if self.at_once else None
        with self._wake:
            self._waiting = frame
            self._wake.notify()
        return answer

    def answer(self, seq: int, timestamp: float) -> LiveAnswer:
        """The stages' prediction for the frame; while a stage is busy beyond ``ANSWER_WAIT_S``,
        the previous answer's pose at this time; before any stage predicts, the estimator's last."""
        estimate, stage_jumps = None, self._stage_jumps
        if self._lock.acquire(timeout=ANSWER_WAIT_S):
            try:
                with self._held_lock:
                    pending = list(self._held)
                estimate = self.pipeline.predict(timestamp, pending)
                stage_jumps = self._stage_jumps = sum(int(getattr(stage, "world_changes", 0)) for stage in self._stages)
            finally:
                self._lock.release()
        elif self._last_answer is not None:
            estimate = replace(self._last_answer, timestamp=timestamp)
        latest = self._latest
        if estimate is None and latest.estimate is not None:
            estimate = replace(latest.estimate, timestamp=timestamp)
        self._last_answer = estimate
        age = None if latest.tracked_at is None else max(0.0, timestamp - latest.tracked_at)
        return LiveAnswer(seq, timestamp, estimate, age, latest.jumps + stage_jumps)

    def _run(self) -> None:
        while True:
            with self._wake:
                while self._waiting is None and not self._closing:
                    self._wake.wait()
                if self._waiting is None:
                    return
                frame, self._waiting = self._waiting, None
            more = True
            while more:  # in batches: the link's thread answers frames between them
                with self._lock:
                    more = self._release(frame.timestamp, RELEASE_BATCH)
            try:
                if self._feed_under_lock:  # the link's thread may release telemetry to it meanwhile
                    with self._lock:
                        self.pipeline.process(frame)
                else:
                    self.pipeline.process(frame)
            except BaseException as exc:  # the link's thread sees it (failed) and ends the session's estimator
                self.failed = exc
                return
            self.visual_frames += 1

    def close(self) -> None:
        """Let the worker finish the frame waiting, then finish the pipeline (unless vision
        failed: then only the stages keep what came)."""
        with self._wake:
            self._closing = True
            self._wake.notify()
        self._worker.join()
        with self._lock:  # what came after the last frame answers no frame (as offline), but the stages keep it
            self._release(float("inf"))
        if self.failed is None:
            self.pipeline.finish()
