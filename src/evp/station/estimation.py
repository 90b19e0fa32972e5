"""One estimator per mobile station, in its own process, fed with the newest frame only.

The process decodes the image and runs the estimator (the same ``make_estimator`` as ``evp run``),
so a slow estimator or a heavy decode never stalls the event loop or another session. The
station side keeps at most one frame waiting: a newer frame replaces it and the replaced one is
reported as dropped (stale), so latency never builds up.
"""

from __future__ import annotations

import asyncio
import multiprocessing
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from evp.geometry.transforms import poses_from_xyz_quat, quat_xyzw_from_matrices
from evp.station.protocol import ImageMessage, Pose, ProtocolError
from evp.types import CameraModel, PoseEstimate


def pose_message(seq: int, estimate: PoseEstimate, reset_counter: int, processing_ms: float) -> Pose:
    """The wire form of an estimate: camera-to-world t and (qw, qx, qy, qz)."""
    qx, qy, qz, qw = quat_xyzw_from_matrices(estimate.T_world_cam[None, :3, :3])[0]
    covariance = None if estimate.covariance is None else [float(v) for v in np.asarray(estimate.covariance).reshape(-1)]
    return Pose(
        seq=seq,
        timestamp=estimate.timestamp,
        t=[float(v) for v in estimate.T_world_cam[:3, 3]],
        q=[float(qw), float(qx), float(qy), float(qz)],
        state=estimate.tracking_state.value,
        quality=int(estimate.quality),
        reset_counter=reset_counter,
        covariance=covariance,
        processing_ms=processing_ms,
    )


def pose_matrix(pose: Pose) -> np.ndarray:
    """T_world_cam (4x4) of a wire pose."""
    qw, qx, qy, qz = pose.q
    return poses_from_xyz_quat(np.array([pose.t]), np.array([[qx, qy, qz, qw]]))[0]


def worker_main(connection, camera: CameraModel, settings_json: str) -> None:
    """The estimator process: ('frame', ImageMessage) in, ('pose', Pose) or ('error', ...) out."""
    from evp.config import Settings
    from evp.errors import EvpError
    from evp.run_setup import make_estimator
    from evp.station.protocol import image_pixels
    from evp.types import Frame

    settings = Settings.model_validate_json(settings_json)
    estimator = make_estimator(camera, settings)
    connection.send(("ready", None))
    while True:
        try:
            item = connection.recv()
        except EOFError:  # the station is gone
            return
        if item is None:
            if hasattr(estimator, "finish"):
                estimator.finish()
            connection.send(("finished", None))
            return
        message: ImageMessage = item
        start = time.perf_counter()
        try:
            image = image_pixels(message)
            estimate = estimator.feed(Frame(message.timestamp, image, index=message.seq, source="stream"))
        except ProtocolError as exc:
            connection.send(("error", (exc.code, exc.message, message.seq)))
        except EvpError as exc:
            connection.send(("error", ("corrupt_image", str(exc), message.seq)))
        else:
            elapsed = (time.perf_counter() - start) * 1000.0
            connection.send(("pose", pose_message(message.seq, estimate, getattr(estimator, "reset_counter", 0), elapsed)))
            if hasattr(estimator, "settle"):
                estimator.settle()  # map the new keyframe (if any) while the pose travels back


@dataclass
class WorkerEvents:
    """What the worker reports back, called on the event loop."""

    on_ready: Callable[[], None]
    on_pose: Callable[[Pose], None]
    on_error: Callable[[str, str, int | None], None]
    on_dropped: Callable[[ImageMessage], None]
    on_exit: Callable[[str], None]


class EstimatorWorker:
    """Async handle on one estimator process."""

    def __init__(self, camera: CameraModel, settings_json: str, events: WorkerEvents):
        self.camera = camera
        self._events = events
        self._loop = asyncio.get_running_loop()
        context = multiprocessing.get_context("spawn")
        self._connection, child = context.Pipe()
        self._process = context.Process(target=worker_main, args=(child, camera, settings_json), name="evp-estimator", daemon=True)
        self._process.start()
        child.close()
        self.ready = False
        self._busy = False
        self._pending: ImageMessage | None = None
        self._closing = False
        self._finished = threading.Event()
        self._reader = threading.Thread(target=self._read_loop, name="evp-estimator-reader", daemon=True)
        self._reader.start()

    def submit(self, message: ImageMessage) -> None:
        """Estimate this frame now, or next; a frame still waiting is dropped as stale."""
        if self._closing:
            self._events.on_dropped(message)
            return
        if self.ready and not self._busy:
            self._send(message)
            return
        if self._pending is not None:
            self._events.on_dropped(self._pending)
        self._pending = message

    def _send(self, message: ImageMessage) -> None:
        self._busy = True
        self._connection.send(message)

    def _read_loop(self) -> None:
        while True:
            try:
                kind, payload = self._connection.recv()
            except (EOFError, OSError):
                self._loop.call_soon_threadsafe(self._on_exit)
                return
            if kind == "finished":
                self._finished.set()
                return
            self._loop.call_soon_threadsafe(self._deliver, kind, payload)

    def _deliver(self, kind: str, payload) -> None:
        if kind == "ready":
            self.ready = True
            self._events.on_ready()
        elif kind == "pose":
            self._events.on_pose(payload)
        elif kind == "error":
            self._events.on_error(*payload)
        if kind in ("pose", "error"):
            self._busy = False
        if self.ready and not self._busy and self._pending is not None:
            message, self._pending = self._pending, None
            self._send(message)

    def _on_exit(self) -> None:
        if not self._closing:
            self._closing = True
            self._events.on_exit(f"estimator process exited (code {self._process.exitcode})")

    async def close(self, timeout: float = 30.0) -> None:
        """Let the frame in progress finish, then stop the process."""
        self._closing = True
        if self._pending is not None:
            self._events.on_dropped(self._pending)
            self._pending = None
        await asyncio.to_thread(self._stop, timeout)

    def _stop(self, timeout: float) -> None:
        try:
            self._connection.send(None)
        except (OSError, ValueError):
            pass
        self._finished.wait(timeout)
        self._process.join(timeout=5)
        if self._process.is_alive():
            self._process.kill()
            self._process.join()
        self._connection.close()
