"""The estimator in a process of its own, beside the process that answers the frames.

Live, a frame's answer (the navigation filter's prediction, a few ms of Python) and vision (SLAM,
30-300 ms of Python a frame) used to share one interpreter. Python runs one thread at a time, so
the answering thread waited for SLAM to hand over the interpreter at each step; on a loaded
machine SLAM's thread is often descheduled while it holds it, and the answer waited for the
operating system too (py-spy on a 30 fps stream: the answering thread spent more time waiting
for the interpreter than working). In two processes they share only the CPUs.

:func:`serve_estimator` runs in the vision process around any :class:`~evp.estimator.Estimator`;
:class:`RemoteEstimator` is that estimator as the answering process sees it: ``feed`` sends the
frame and waits (without the interpreter) for its estimate, with the estimator's reset counter
and loop closures; ``settle`` is done by the vision process right after it has answered, as the
pipeline would. A frame the estimator rejects comes back as :class:`FrameRejected` (an
``EvpError``: the pipeline skips the frame); a vision process that dies is
:class:`VisionProcessLost`.
"""

from __future__ import annotations

from typing import Any

from evp.errors import DataError, EvpError
from evp.estimator import Estimator
from evp.types import Frame, PoseEstimate


class FrameRejected(DataError):
    """The estimator in the vision process refused a frame (its own message)."""


class VisionProcessLost(RuntimeError):
    """The vision process ended without being asked to (killed, or a bug in the estimator)."""


def serve_estimator(connection, estimator: Estimator) -> None:
    """The vision process's loop: ``("feed", frame)``, ``("observe", record)`` and ``("finish",
    None)`` from the answering process, until it finishes or goes away. Says ``("ready", info)``
    first: whether the estimator starts in a saved map, and whether it uses telemetry (an EKF-SLAM
    predicts with the wheels; SLAM takes none, so none is sent)."""
    observes = type(estimator).observe is not Estimator.observe
    connection.send(("ready", {"in_saved_map": bool(getattr(estimator, "in_saved_map", False)), "observes": observes}))
    closures_told = 0
    try:
        while True:
            try:
                kind, payload = connection.recv()
            except EOFError:  # the answering process is gone
                return
            if kind == "observe":
                estimator.observe(payload)
            elif kind == "feed":
                try:
                    estimate = estimator.feed(payload)
                except EvpError as exc:
                    connection.send(("rejected", str(exc)))
                    continue
                closures = list(getattr(estimator, "loop_closures", ()))
                connection.send(("estimate", (estimate, int(getattr(estimator, "reset_counter", 0)), closures[closures_told:])))
                closures_told = len(closures)
                estimator.settle()
            elif kind == "finish":
                estimator.finish()
                connection.send(("finished", None))
                return
    finally:
        estimator.close()


class RemoteEstimator(Estimator):
    """The estimator that :func:`serve_estimator` runs, seen from the answering process."""

    def __init__(self, connection):
        self._connection = connection
        info = self._receive("ready")
        self.in_saved_map: bool = info["in_saved_map"]
        self._observes: bool = info["observes"]
        self.reset_counter = 0
        self.loop_closures: list = []

    def _receive(self, expected: str) -> Any:
        try:
            kind, payload = self._connection.recv()
        except (EOFError, OSError) as exc:
            raise VisionProcessLost("the vision process ended") from exc
        if kind == "rejected" and expected == "estimate":
            raise FrameRejected(payload)
        if kind != expected:
            raise VisionProcessLost(f"the vision process said {kind!r} where {expected!r} was due")
        return payload

    def _send(self, message: tuple) -> None:
        try:
            self._connection.send(message)
        except (OSError, ValueError) as exc:
            raise VisionProcessLost("the vision process ended") from exc

    def feed(self, frame: Frame) -> PoseEstimate:
        self._send(("feed", frame))
        estimate, self.reset_counter, closures = self._receive("estimate")
        self.loop_closures.extend(closures)
        return estimate

    def observe(self, record: Any) -> None:
        if self._observes:
            self._send(("observe", record))

    def finish(self) -> None:
        self._send(("finish", None))
        self._receive("finished")
