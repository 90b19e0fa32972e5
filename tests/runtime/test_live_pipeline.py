"""The pipeline driven live: every frame answered at once with the navigation filter's estimate
while vision is busy, vision correcting the filter when it is ready (exact visual poses and IMU
of a known trajectory, as in tests/fusion/test_navigation_stage.py)."""

from __future__ import annotations

import threading

import numpy as np

from evp.config import NavigationSettings
from evp.estimator import Estimator
from evp.fusion.navigation_stage import NavigationStage
from evp.pipeline import Pipeline, Sink, run_frames
from evp.runtime.live_pipeline import LivePipeline
from evp.types import Frame, PoseEstimate, TrackingState
from tests.fusion.inertial_trajectory import SinusoidTrajectory, imu_times
from tests.fusion.test_navigation_filter import T_BODY_CAM
from tests.fusion.test_navigation_stage import EXACT_IMU, map_pose

FRAME_RATE = 20.0


class _GatedVision(Estimator):
    """Answers a frame with its exact map pose once ``gate`` is open; ``entered`` is set when it
    starts on a frame."""

    def __init__(self, trajectory):
        self.trajectory = trajectory
        self.gate = threading.Event()
        self.gate.set()
        self.entered = threading.Event()
        self.frames: list[int] = []

    def feed(self, frame: Frame) -> PoseEstimate:
        self.entered.set()
        self.gate.wait()
        self.frames.append(frame.index)
        return PoseEstimate(frame.timestamp, map_pose(self.trajectory, frame.timestamp), TrackingState.OK, 80)


class _Done(Sink):
    """Counts the pipeline's answers (after the live pipeline has taken them in)."""

    def __init__(self):
        self.fed = threading.Semaphore(0)

    def on_estimate(self, frame: Frame, estimate: PoseEstimate, elapsed_ms: float) -> None:
        self.fed.release()


def _frame(index: int, t: float) -> Frame:
    return Frame(t, np.zeros((2, 2), np.uint8), index)


def test_frames_are_answered_at_once_from_the_filter_while_vision_is_busy():
    trajectory = SinusoidTrajectory()
    vision = _GatedVision(trajectory)
    stage = NavigationStage(T_BODY_CAM, EXACT_IMU, lambda: vision.reset_counter)
    done = _Done()
    live = LivePipeline(Pipeline(vision, [done], [stage]))
    imu = iter(trajectory.imu(imu_times(6.0)))
    sample = next(imu)
    answers = []

    def step(k: int, wait_for_vision: bool):
        nonlocal sample
        t = k / FRAME_RATE
        while sample is not None and sample.timestamp <= t:
            live.telemetry(sample)
            sample = next(imu, None)
        answers.append(live.frame(_frame(k, t)))
        if wait_for_vision:
            assert done.fed.acquire(timeout=10)

    try:
        for k in range(60):  # 3 s with vision keeping up: the filter starts at 2 s
            step(k, wait_for_vision=True)
        assert stage.filter is not None
        while done.fed.acquire(blocking=False):
            pass
        vision.gate.clear()  # vision stalls (a long mapping step) for 1 s
        vision.entered.clear()
        step(60, wait_for_vision=False)
        assert vision.entered.wait(timeout=10)  # it took frame 60 and stalls on it
        for k in range(61, 80):
            step(k, wait_for_vision=False)
        stalled = answers[61:80]
        # the filter waits for vision (delayed horizon at frame 60's time); the answers ran ahead of it on the IMU
        assert stage.filter.state.timestamp <= 3.0 + 1e-9
        vision.gate.set()
        assert done.fed.acquire(timeout=10) and done.fed.acquire(timeout=10)  # the frame it held, then the newest waiting
        step(80, wait_for_vision=True)
    finally:
        vision.gate.set()
        live.close()

    assert [a.seq for a in answers] == list(range(81))
    assert answers[0].estimate is None  # nothing from vision yet, no filter
    assert not answers[10].estimate.metric and abs(answers[10].visual_age_s - 0.05) < 1e-9  # the last visual pose, carried
    # while vision stalls every frame is still answered, metric, from the IMU-propagated filter,
    # its visual age growing; the exact IMU keeps it on the truth
    assert all(a.estimate.metric for a in stalled)
    ages = [a.visual_age_s for a in stalled]
    assert np.all(np.diff(ages) > 0) and ages[-1] > 0.9
    # and where the same pipeline run offline, with vision on every frame, puts the camera
    reference = run_frames(
        _GatedVision(trajectory), [_frame(k, k / FRAME_RATE) for k in range(81)], stages=[NavigationStage(T_BODY_CAM, EXACT_IMU)],
        telemetry=trajectory.imu(imu_times(4.01)),
    ).estimates  # fmt: skip
    for answer in stalled:
        offline = reference[answer.seq]
        assert np.linalg.norm(answer.estimate.T_world_cam[:3, 3] - offline.T_world_cam[:3, 3]) < 0.01
        assert answer.estimate.covariance.shape == (6, 6)
    # vision took the frame it was given when it stalled and then only the newest waiting one
    assert vision.frames[60:] == [60, 79, 80]
    assert answers[-1].visual_age_s < 0.06
    assert answers[-1].reset_counter == 1  # the filter's start changed the answered frame once


def test_without_stages_the_estimators_last_pose_is_carried_with_its_age():
    trajectory = SinusoidTrajectory()
    vision = _GatedVision(trajectory)
    done = _Done()
    live = LivePipeline(Pipeline(vision, [done], []))
    try:
        first = live.frame(_frame(0, 0.0))
        assert done.fed.acquire(timeout=10)
        second = live.frame(_frame(1, 0.5))
    finally:
        live.close()
    assert first.estimate is None and first.visual_age_s is None
    assert abs(second.visual_age_s - 0.5) < 1e-9 and second.estimate.timestamp == 0.5
    np.testing.assert_allclose(second.estimate.T_world_cam, map_pose(trajectory, 0.0))


def test_every_jump_of_the_estimator_steps_the_answers_reset_counter():
    """A new map or relocalisation (the estimator's reset counter) and a loop correction (its
    loop closures, which SLAM's counter leaves out) each step the answers' counter."""
    trajectory = SinusoidTrajectory()
    vision = _GatedVision(trajectory)
    vision.loop_closures = []
    done = _Done()
    live = LivePipeline(Pipeline(vision, [done], []))
    counters = []
    try:
        for k, jump in enumerate([None, "map reset", None, "loop correction", None]):
            if jump == "map reset":
                vision.reset_counter += 1
            elif jump == "loop correction":
                vision.loop_closures.append(object())
            live.frame(_frame(k, 0.1 * k))
            assert done.fed.acquire(timeout=10)
            counters.append(live.answer(k, 0.1 * k + 0.01).reset_counter)
    finally:
        live.close()
    assert counters == [0, 1, 1, 2, 2]


class _SlowStage:
    """A stage whose processing of frame ``slow_frame`` stays busy (the visual-inertial start's
    solve) until ``release`` is set; ``busy`` is set when it starts. It keeps every record it is
    given and predicts the estimate it last processed, carried to the asked time."""

    def __init__(self, slow_frame: int):
        self.slow_frame, self.busy, self.release = slow_frame, threading.Event(), threading.Event()
        self.records, self.last = [], None

    def observe(self, record) -> None:
        self.records.append(record)

    def process(self, frame: Frame, estimate: PoseEstimate) -> PoseEstimate:
        if frame.index == self.slow_frame:
            self.busy.set()
            assert self.release.wait(timeout=10)
        self.last = estimate
        return estimate

    def predict(self, timestamp: float, pending=()) -> PoseEstimate | None:
        return None if self.last is None else PoseEstimate(timestamp, self.last.T_world_cam, TrackingState.OK, 80)


def test_a_stage_busy_in_a_long_call_holds_up_neither_telemetry_nor_answers():
    """The link's thread goes on while the stages' lock is held: telemetry is held for later and
    each answer is the previous one's pose at its own time; once the stage is done, every record
    reaches it in order and answers come from it again."""
    trajectory = SinusoidTrajectory()
    stage = _SlowStage(slow_frame=1)
    done = _Done()
    live = LivePipeline(Pipeline(_GatedVision(trajectory), [done], [stage]))
    imu = trajectory.imu(imu_times(2.0))
    try:
        live.frame(_frame(0, 0.0))
        assert done.fed.acquire(timeout=10)
        before = live.answer(0, 0.01)
        live.frame(_frame(1, 0.05))
        assert stage.busy.wait(timeout=10)  # the vision thread is inside the stage, holding its lock
        for sample in imu[:300]:  # 1.5 s of IMU: records older than max_hold_s would go to the stage now
            live.telemetry(sample)
        while_busy = [live.answer(k, 0.05 + 0.05 * k) for k in range(2, 6)]
        assert len(stage.records) == 0  # held, not lost: the stage could not take them
        stage.release.set()
        assert done.fed.acquire(timeout=10)
        for sample in imu[300:]:
            live.telemetry(sample)
        after = live.answer(7, 0.4)
    finally:
        stage.release.set()
        live.close()
    assert [a.timestamp for a in while_busy] == [0.05 + 0.05 * k for k in range(2, 6)]
    for answer in while_busy:
        np.testing.assert_array_equal(answer.estimate.T_world_cam, before.estimate.T_world_cam)
    assert [r.timestamp for r in stage.records] == [s.timestamp for s in imu]  # every record, in order, once
    np.testing.assert_allclose(after.estimate.T_world_cam, map_pose(trajectory, 0.05))


class _VisionThatFails(Estimator):
    """Loses its vision process (or cluster worker) on the second frame."""

    finished = False

    def feed(self, frame: Frame) -> PoseEstimate:
        if frame.index == 1:
            raise RuntimeError("the vision process ended")
        return PoseEstimate(frame.timestamp, np.eye(4), TrackingState.OK, 80)

    def finish(self) -> None:
        self.finished = True


def test_vision_that_fails_is_told_to_the_link_and_not_finished():
    estimator = _VisionThatFails()
    live = LivePipeline(Pipeline(estimator))
    live.frame(Frame(0.0, np.zeros((2, 2), np.uint8), index=0))
    live.frame(Frame(0.1, np.zeros((2, 2), np.uint8), index=1))
    live._worker.join(10)
    assert isinstance(live.failed, RuntimeError) and "vision process ended" in str(live.failed)
    live.close()
    assert not estimator.finished, "a lost estimator is not asked to finish"


class _ObservingVision(_GatedVision):
    """Takes telemetry itself (SLAM's gyro, the EKF-SLAM's wheels)."""

    def __init__(self, trajectory, in_order: bool):
        super().__init__(trajectory)
        self.observes_while_feeding = in_order
        self.records: list = []

    def observe(self, record) -> None:
        self.records.append(record)


def test_an_estimator_that_keeps_its_calls_in_order_is_fed_outside_the_stages_lock():
    """An estimator in the vision process takes the pipe's messages in order, so its frames go
    without the stages' lock and the answers at once never wait for them; one in this process
    that observes is fed under it, so that no record reaches it in the middle of a frame."""
    held = {}
    for in_order in (True, False):
        vision = _ObservingVision(SinusoidTrajectory(), in_order)
        live = LivePipeline(Pipeline(vision, [_Done()]))
        try:
            vision.gate.clear()
            live.frame(_frame(0, 0.0))
            assert vision.entered.wait(timeout=10)
            free = live.locked().acquire(blocking=False)
            if free:
                live.locked().release()
            held[in_order] = not free
        finally:
            vision.gate.set()
            live.close()
    assert held == {True: False, False: True}
