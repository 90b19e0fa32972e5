"""The estimator away from the process that answers the frames: in a vision process of its own
beside it, or on a cluster's worker (a fleet).

Live, a frame's answer (the navigation filter's prediction, a few ms of Python) and vision (SLAM,
30-300 ms of Python a frame) used to share one interpreter. Python runs one thread at a time, so
the answering thread waited for SLAM to hand over the interpreter at each step; on a loaded
machine SLAM's thread is often descheduled while it holds it, and the answer waited for the
operating system too (py-spy on a 30 fps stream: the answering thread spent more time waiting
for the interpreter than working). In two processes they share only the CPUs; on a cluster, not
even those.

:class:`EstimatorServer` is the estimator's side, whatever carries the calls: a pipe
(:func:`serve_estimator`, in the vision process) or a Dask actor (on a worker). The answering
side sees an :class:`~evp.estimator.Estimator`: :class:`RemoteEstimator` over the pipe,
:class:`ClusterEstimator` over the actor. ``feed`` sends the frame and waits (without the
interpreter) for its estimate, with the estimator's reset counter and loop closures; ``settle``
is done by the server right after it has answered, as the pipeline would. A frame the estimator
rejects comes back as :class:`FrameRejected` (an ``EvpError``: the pipeline skips the frame); a
server that is gone is :class:`VisionLost`.
"""

from __future__ import annotations

import os
import threading
from typing import Any

from evp.errors import DataError, EvpError
from evp.estimator import Estimator
from evp.types import Frame, PoseEstimate


class FrameRejected(DataError):
    """The estimator in the vision process or on the cluster refused a frame (its own message)."""


class VisionLost(RuntimeError):
    """The vision process or the cluster's worker ended without being asked to (killed, or a bug
    in the estimator)."""


class ThreadPriority:
    """A lower scheduling priority for the threads that run an estimator (``station.vision_nice``),
    so that where they share CPUs with the processes that answer the frames (a station's cores, a
    local cluster), the answers run first and vision takes what is left. The cost is SLAM's share:
    with two 30 fps flights on two cores, five steps below halved the answers' p95 but one
    vehicle's filter never started (docs/decisions.md), so stations use it only when other work
    oversubscribes their cores.

    Linux gives each thread its own niceness and a new thread its creator's, so :meth:`lower`
    is called by every thread that runs the estimator's calls (a cluster's actor runs them on a
    thread of its own), and before the estimator starts its threads. Raising a priority back
    needs privileges a station rarely has: a thread is only ever lowered, once."""

    def __init__(self, niceness: int):
        self.value = min(19, os.getpriority(os.PRIO_PROCESS, 0) + niceness)  # below the creating thread's
        self._lowered: set[int] = set()

    def lower(self) -> None:
        """The calling thread to this priority (once; never raised)."""
        thread = threading.get_native_id()
        if thread not in self._lowered:
            self._lowered.add(thread)
            if os.getpriority(os.PRIO_PROCESS, thread) < self.value:
                os.setpriority(os.PRIO_PROCESS, thread, self.value)


class EstimatorServer:
    """An estimator's calls as plain data: what each side of a link needs, and nothing else;
    each call's thread runs at ``priority`` when one is given."""

    def __init__(self, estimator: Estimator, priority: ThreadPriority | None = None):
        self.estimator = estimator
        self.priority = priority
        self._closures_told = 0

    def _lower(self) -> None:
        if self.priority is not None:
            self.priority.lower()

    def info(self) -> dict:
        """Whether the estimator starts in a saved map, and whether it uses telemetry (an
        EKF-SLAM predicts with the wheels; SLAM takes none, so none need be sent)."""
        return {"in_saved_map": bool(getattr(self.estimator, "in_saved_map", False)), "observes": self.estimator.uses_telemetry}

    def feed(self, frame: Frame) -> tuple[str, Any]:
        """``("estimate", (estimate, reset counter, loop closures since the last answer))``, or
        ``("rejected", why)`` for a frame the estimator refused."""
        self._lower()
        try:
            estimate = self.estimator.feed(frame)
        except EvpError as exc:
            return "rejected", str(exc)
        closures = list(getattr(self.estimator, "loop_closures", ()))
        new, self._closures_told = closures[self._closures_told :], len(closures)
        return "estimate", (estimate, int(getattr(self.estimator, "reset_counter", 0)), new)

    def observe(self, records: list) -> None:
        """The telemetry that came before the next frame, in order."""
        self._lower()
        for record in records:
            self.estimator.observe(record)

    def settle(self) -> None:
        self._lower()
        self.estimator.settle()

    def finish(self) -> None:
        self.estimator.finish()

    def close(self) -> None:
        self.estimator.close()


def serve_estimator(connection, server: EstimatorServer) -> None:
    """The vision process's loop: ``("feed", frame)``, ``("observe", records)`` and ``("finish",
    None)`` from the answering process, until it finishes or goes away; says ``("ready", info)``
    first."""
    connection.send(("ready", server.info()))
    try:
        while True:
            try:
                kind, payload = connection.recv()
            except EOFError:  # the answering process is gone
                return
            if kind == "observe":
                server.observe(payload)
            elif kind == "feed":
                answer = server.feed(payload)
                connection.send(answer)
                if answer[0] == "estimate":  # as the pipeline: a rejected frame started nothing
                    server.settle()
            elif kind == "finish":
                server.finish()
                connection.send(("finished", None))
                return
    finally:
        server.close()


class _ServedEstimator(Estimator):
    """The answering side's view of an :class:`EstimatorServer`: the estimator's counters
    mirrored from each answer. Telemetry is held here and goes with the next frame, in one call:
    the estimator gets every record before the frame it precedes, as a local one would, and the
    thread that hands it over never waits on the link (a vision process busy for seconds with a
    loop's adjustment filled its pipe with 200 IMU samples a second, and the answers stopped)."""

    observes_while_feeding = True

    @property
    def uses_telemetry(self) -> bool:
        return self._observes

    def _start(self, info: dict) -> None:
        self.in_saved_map: bool = info["in_saved_map"]
        self._observes: bool = info["observes"]
        self.reset_counter = 0
        self.loop_closures: list = []
        self._pending: list = []
        self._pending_lock = threading.Lock()

    def observe(self, record: Any) -> None:
        if self._observes:
            with self._pending_lock:
                self._pending.append(record)

    def _take_pending(self) -> list:
        """The records held since the last frame, now handed over."""
        with self._pending_lock:
            records, self._pending = self._pending, []
        return records

    def _answer(self, kind: str, payload: Any) -> PoseEstimate:
        if kind == "rejected":
            raise FrameRejected(payload)
        if kind != "estimate":
            raise VisionLost(f"the estimator's server said {kind!r} where an estimate was due")
        estimate, self.reset_counter, closures = payload
        self.loop_closures.extend(closures)
        return estimate


class RemoteEstimator(_ServedEstimator):
    """The estimator that :func:`serve_estimator` runs in the vision process, over its pipe."""

    def __init__(self, connection):
        self._connection = connection
        kind, info = self._receive()
        if kind != "ready":
            raise VisionLost(f"the vision process said {kind!r} where 'ready' was due")
        self._start(info)

    def _receive(self) -> tuple[str, Any]:
        try:
            return self._connection.recv()
        except (EOFError, OSError) as exc:
            raise VisionLost("the vision process ended") from exc

    def _send(self, message: tuple) -> None:
        try:
            self._connection.send(message)
        except (OSError, ValueError) as exc:
            raise VisionLost("the vision process ended") from exc

    def feed(self, frame: Frame) -> PoseEstimate:
        records = self._take_pending()
        if records:
            self._send(("observe", records))
        self._send(("feed", frame))
        return self._answer(*self._receive())

    def finish(self) -> None:
        self._send(("finish", None))
        if self._receive()[0] != "finished":
            raise VisionLost("the vision process did not finish")


class ClusterEstimator(_ServedEstimator):
    """An estimator placed on a Dask cluster's worker: ``server_class(*args)`` (an
    :class:`EstimatorServer` built there) as an actor, one per session for the session's life.
    The actor runs one call at a time, in order, so the estimator sees its frames and telemetry as
    a local one would; ``settle`` is sent after each answer and not waited for."""

    def __init__(self, address: str, server_class: type, *args, timeout_s: float = 60.0):
        from distributed import Client

        self.timeout_s = timeout_s
        try:  # not the process's default client: the actor's calls name theirs (as_current)
            self._client = Client(address, timeout=timeout_s, set_as_default=False)
            with self._client.as_current():
                self._actor = self._client.submit(server_class, *args, actor=True).result(timeout=timeout_s)
        except (OSError, TimeoutError) as exc:
            raise VisionLost(f"the cluster at {address} gave no estimator ({exc})") from exc
        self._start(self._call("info"))

    def _call(self, method: str, *args, wait: bool = True):
        try:
            with self._client.as_current():
                future = getattr(self._actor, method)(*args)
                return future.result(timeout=self.timeout_s) if wait else future
        except (OSError, TimeoutError, ValueError) as exc:  # the worker or the scheduler is gone
            raise VisionLost(f"the cluster's estimator is gone ({exc})") from exc

    def feed(self, frame: Frame) -> PoseEstimate:
        records = self._take_pending()
        if records:
            self._call("observe", records, wait=False)  # the actor runs it before the frame: calls run in order
        estimate = self._answer(*self._call("feed", frame))
        self._call("settle", wait=False)
        return estimate

    def finish(self) -> None:
        try:
            self._call("finish")
        finally:
            self._client.close()

    def close(self) -> None:
        self._client.close()
