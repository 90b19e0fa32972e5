"""The estimator in a vision process of its own: the answering process sees the same estimator
(estimates, reset counter, loop closures, rejected frames, telemetry), and the pair of processes
lives and dies together."""

from __future__ import annotations

import asyncio
import multiprocessing
import os
import threading

import numpy as np
import pytest

from evp.errors import DataError, EvpError
from evp.estimator import Estimator
from evp.pipeline import Pipeline, RunResult
from evp.runtime.estimator_process import EstimatorProcess, ProcessEvents
from evp.runtime.vision_process import EstimatorServer, RemoteEstimator, ThreadPriority, VisionLost, serve_estimator
from evp.types import Frame, PoseEstimate, TrackingState


class _Scripted(Estimator):
    """Answers frame k at x = k; resets at frame 2, closes a loop at frame 3, rejects frame 5;
    keeps what was settled. Uses no telemetry."""

    def __init__(self):
        self.loop_closures: list[str] = []
        self.observed: list = []
        self.settled: list[int] = []
        self._last = -1

    def feed(self, frame: Frame) -> PoseEstimate:
        if frame.index == 5:
            raise DataError(f"frame {frame.index}: too dark")
        self._last = frame.index
        self.reset_counter += frame.index == 2
        if frame.index == 3:
            self.loop_closures.append("loop at 3")
        T = np.eye(4)
        T[0, 3] = frame.index
        return PoseEstimate(frame.timestamp, T, TrackingState.OK, 90)

    def settle(self) -> None:
        self.settled.append(self._last)


class _Observing(_Scripted):
    """The same, keeping the telemetry it observes (as an EKF-SLAM uses the wheels)."""

    def observe(self, record) -> None:
        self.observed.append((record, self._last))  # with the last frame fed before it


def _frames(count: int) -> list[Frame]:
    return [Frame(0.1 * k, np.zeros((4, 4), np.uint8), index=k) for k in range(count)]


def test_the_remote_estimator_is_the_estimator_seen_through_a_pipe():
    ours, theirs = multiprocessing.Pipe()
    scripted = _Observing()
    server = threading.Thread(target=serve_estimator, args=(theirs, EstimatorServer(scripted)))
    server.start()
    remote = RemoteEstimator(ours)
    result = RunResult(remote)
    pipeline = Pipeline(remote, [result])
    pipeline.telemetry("imu 0")
    for frame in _frames(7):
        if frame.index == 3:
            pipeline.telemetry("imu 1")
            pipeline.telemetry("imu 2")
        pipeline.process(frame)
    pipeline.finish()
    server.join(10)
    assert [e.T_world_cam[0, 3] for e in result.estimates] == [0, 1, 2, 3, 4, 6]
    assert result.skipped == ["frame 5: too dark"]
    assert remote.reset_counter == 1 and remote.loop_closures == ["loop at 3"]
    # every record before the frame it precedes, in order (held by the remote side and sent with that frame)
    assert scripted.observed == [("imu 0", -1), ("imu 1", 2), ("imu 2", 2)] and scripted.settled == [0, 1, 2, 3, 4, 6]


def test_telemetry_is_not_sent_to_an_estimator_that_uses_none():
    ours, theirs = multiprocessing.Pipe()
    scripted = _Scripted()
    server = threading.Thread(target=serve_estimator, args=(theirs, EstimatorServer(scripted)))
    server.start()
    remote = RemoteEstimator(ours)
    remote.observe("imu 0")
    remote.finish()
    server.join(10)
    assert not remote._observes and scripted.observed == []


def test_a_vision_process_that_is_gone_is_named():
    ours, theirs = multiprocessing.Pipe()
    theirs.send(("ready", {"in_saved_map": True, "observes": False}))
    remote = RemoteEstimator(ours)
    assert remote.in_saved_map
    theirs.close()
    with pytest.raises(VisionLost):
        remote.feed(_frames(1)[0])
    assert not issubclass(VisionLost, EvpError), "a lost process is not the user's input"


def _answers_until_told(connection, vision) -> None:
    """An estimator process that says it is ready and waits for the end of the stream."""
    connection.send(("ready", None))
    while connection.recv() is not None:
        pass
    connection.send(("finished", None))


def _vision_that_dies(connection, code: int) -> None:
    os._exit(code)


def _vision_that_waits(connection) -> None:
    """Ends when the estimator process does (its end of the pipe closes)."""
    try:
        connection.recv()
    except EOFError:
        pass


def test_the_pair_dies_together_and_the_death_of_vision_is_named():
    exits: list[str] = []

    async def scenario() -> EstimatorProcess:
        ended = asyncio.Event()
        events = ProcessEvents(lambda: None, print, print, print, lambda reason: (exits.append(reason), ended.set()))
        process = EstimatorProcess(_answers_until_told, (), events, partner=(_vision_that_dies, (3,)))
        await asyncio.wait_for(ended.wait(), 60)
        await process.close()
        return process

    process = asyncio.run(scenario())
    assert exits == ["vision process exited (code 3)"]
    assert process._process.exitcode is not None, "the estimator process was stopped with its partner"


def test_a_pair_asked_to_close_is_not_an_exit():
    exits: list[str] = []

    async def scenario() -> None:
        ready = asyncio.Event()
        events = ProcessEvents(ready.set, print, print, print, exits.append)
        process = EstimatorProcess(_answers_until_told, (), events, partner=(_vision_that_waits, ()))
        await asyncio.wait_for(ready.wait(), 60)
        await process.close()

    asyncio.run(scenario())
    assert exits == []


def test_the_estimator_threads_run_below_the_answering_ones_and_are_lowered_once():
    base = os.getpriority(os.PRIO_PROCESS, 0)
    priority = ThreadPriority(3)
    seen: dict[str, int] = {}

    def estimator_thread() -> None:
        priority.lower()
        priority.lower()  # once: not 6 below
        seen["lowered"] = os.getpriority(os.PRIO_PROCESS, 0)
        child = threading.Thread(target=lambda: seen.setdefault("child", os.getpriority(os.PRIO_PROCESS, 0)))
        child.start()
        child.join()

    thread = threading.Thread(target=estimator_thread)
    thread.start()
    thread.join()
    assert seen == {"lowered": min(19, base + 3), "child": min(19, base + 3)}, "a thread the estimator starts inherits it"
    assert os.getpriority(os.PRIO_PROCESS, 0) == base, "the answering thread keeps its priority"
