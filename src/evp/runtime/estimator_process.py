"""A pipeline in its own process, fed the newest frame only (the live pacing policy).

The process runs ``target(connection, *args)``: the station's adapter, which decodes the wire
messages into frames and drives the one :class:`evp.pipeline.Pipeline`. This side keeps at most
one message waiting: a newer message replaces it and the replaced one is reported as dropped
(stale), so latency never builds up, and a slow estimator or a heavy decode never stalls the event
loop or another session.

The process speaks a small protocol over its pipe: ``("ready", None)`` once it can take frames,
``("pose", payload)`` or ``("error", payload)`` for each message it was sent, ``("finished",
None)`` after the ``None`` that ends the stream, and any other ``(kind, payload)`` as a report
(``on_report``). Side messages (:meth:`EstimatorProcess.send_side`: telemetry) go at once, never
wait and are never dropped: the process reads its pipe all the time.
"""

from __future__ import annotations

import asyncio
import multiprocessing
import threading
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any


@dataclass
class ProcessEvents:
    """What the process reports back, called on the event loop."""

    on_ready: Callable[[], None]
    on_pose: Callable[[Any], None]
    on_error: Callable[..., None]  # called with the error payload's items
    on_dropped: Callable[[Any], None]  # a message never sent to the process
    on_exit: Callable[[str], None]  # the process ended without being asked to
    on_report: Callable[[str, Any], None] = lambda kind, payload: None  # anything else the process says


class EstimatorProcess:
    """Async handle on one estimator process; create it on the event loop that gets the events."""

    def __init__(self, target: Callable[..., None], args: tuple, events: ProcessEvents, name: str = "evp-estimator", every_message: bool = False):
        """``every_message``: once the process is ready, every message goes to it at once (a
        process that answers each message itself at once, keeping its own newest-first slot);
        before that the newest one waits, as always."""
        self._events = events
        self._every_message = every_message
        self._loop = asyncio.get_running_loop()
        # spawn, not fork: the station runs an event loop and threads a forked child would inherit
        context = multiprocessing.get_context("spawn")
        self._connection, child = context.Pipe()
        self._process = context.Process(target=target, args=(child, *args), name=name, daemon=True)
        self._process.start()
        child.close()
        self.ready = False
        self._busy = False
        self._pending: Any = None
        self._closing = False
        self._finished = threading.Event()
        self._reader = threading.Thread(target=self._read_loop, name=f"{name}-reader", daemon=True)
        self._reader.start()

    def submit(self, message: Any) -> None:
        """Send this message now, or next; a message still waiting is dropped as stale."""
        if self._closing:
            self._events.on_dropped(message)
            return
        if self.ready and (self._every_message or not self._busy):
            self._send(message)
            return
        if self._pending is not None:
            self._events.on_dropped(self._pending)
        self._pending = message

    def send_side(self, message: Any) -> None:
        """A message outside the frame policy (telemetry): sent now, in order with the frames sent."""
        if not self._closing:
            self._send(message, frame=False)

    def _send(self, message: Any, frame: bool = True) -> None:
        """To the process; a process that died meanwhile is reported by the reader (on_exit), and
        the frame stays with its sender, which answers it then."""
        self._busy = self._busy or frame
        try:
            self._connection.send(message)
        except (OSError, ValueError):  # broken pipe: the process is gone
            pass

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

    def _deliver(self, kind: str, payload: Any) -> None:
        if kind == "ready":
            self.ready = True
            self._events.on_ready()
        elif kind == "pose":
            self._events.on_pose(payload)
        elif kind == "error":
            self._events.on_error(*payload)
        else:
            self._events.on_report(kind, payload)
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
        """Let the message in progress finish, end the stream, then stop the process."""
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
