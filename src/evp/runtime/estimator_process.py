"""A pipeline in its own process, fed the newest frame only (the live pacing policy).

The process runs ``target(connection, *args)``: the station's adapter, which decodes the wire
messages into frames and drives the one :class:`evp.pipeline.Pipeline`. This side keeps at most
one message waiting: a newer message replaces it and the replaced one is reported as dropped
(stale), so latency never builds up, and a slow estimator or a heavy decode never stalls the event
loop or another session.

The process speaks a small protocol over its pipe: ``("ready", None)`` once it can take frames,
``("pose", payload)`` or ``("error", payload)`` for each message it was sent, ``("finished",
None)`` after the ``None`` that ends the stream, and any other ``(kind, payload)`` as a report
(``on_report``). With a ``partner`` (the vision process of ``evp.runtime.vision_process``), a second process
is started beside it, the two joined by a pipe of their own; the pair lives and dies together: the
death of either is the estimator's exit. Side messages (:meth:`EstimatorProcess.send_side`: telemetry) go at once, never
wait and are never dropped: the process reads its pipe all the time.

Writing to the pipe blocks while its buffer (64 kB, less than one VGA JPEG) is full, which it is
whenever the process's link thread is slow to read (it waits for the GIL while SLAM holds it). So
a writer thread writes, never the event loop: measured with py-spy on a 30 fps stream, the
station's event loop spent 28 % of its time blocked in that write, and every session's answers
waited behind it.
"""

from __future__ import annotations

import asyncio
import multiprocessing
import threading
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from multiprocessing.connection import wait
from typing import Any

# Frames written to the pipe's buffer wait there for the process; with ``every_message`` more can
# pile up in the writer while the process does not read. Beyond this many unwritten frames (a
# tenth of a second at 30 fps) the oldest one is dropped as stale: an answer that late is no use
# to a vehicle, and the latency would otherwise grow without bound.
MAX_FRAMES_UNWRITTEN = 3

_END = object()  # the writer's last item: it sends the None that ends the stream and stops


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

    def __init__(
        self,
        target: Callable[..., None],
        args: tuple,
        events: ProcessEvents,
        name: str = "evp-estimator",
        every_message: bool = False,
        partner: tuple[Callable[..., None], tuple] | None = None,
    ):
        """``every_message``: once the process is ready, every message goes to it at once (a
        process that answers each message itself at once, keeping its own newest-first slot);
        before that the newest one waits, as always. ``partner``: ``(target, args)`` of the
        second process; it runs ``target(its_end, *args)`` and this one gets the other end of
        their pipe as its last argument."""
        self._events = events
        self._every_message = every_message
        self._loop = asyncio.get_running_loop()
        # spawn, not fork: the station runs an event loop and threads a forked child would inherit
        context = multiprocessing.get_context("spawn")
        self._connection, child = context.Pipe()
        self._partner = None
        self._partner_died = False  # the partner ended first (the reader then stopped this one)
        if partner is not None:
            ours, theirs = context.Pipe()
            self._partner = context.Process(target=partner[0], args=(theirs, *partner[1]), name=f"{name}-vision", daemon=True)
            self._partner.start()
            theirs.close()
            args = (*args, ours)
        self._process = context.Process(target=target, args=(child, *args), name=name, daemon=True)
        self._process.start()
        child.close()
        if partner is not None:
            ours.close()
        self.ready = False
        self._busy = False
        self._pending: Any = None
        self._closing = False
        self._finished = threading.Event()
        self._outbox: deque[tuple[Any, bool]] = deque()  # (message, is a frame), oldest first
        self._outbox_filled = threading.Condition()
        self._writer = threading.Thread(target=self._write_loop, name=f"{name}-writer", daemon=True)
        self._writer.start()
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
        """To the writer, in order; a frame that finds ``MAX_FRAMES_UNWRITTEN`` frames still
        unwritten replaces the oldest, which is dropped (stale)."""
        self._busy = self._busy or frame
        stale = None
        with self._outbox_filled:
            if frame and sum(is_frame for _, is_frame in self._outbox) >= MAX_FRAMES_UNWRITTEN:
                oldest = next(i for i, (_, is_frame) in enumerate(self._outbox) if is_frame)
                stale = self._outbox[oldest][0]
                del self._outbox[oldest]
            self._outbox.append((message, frame))
            self._outbox_filled.notify()
        if stale is not None:
            self._events.on_dropped(stale)

    def _write_loop(self) -> None:
        """Writes the outbox to the process; a process that died meanwhile is reported by the
        reader (on_exit), and the frames stay with their sender, which answers them then."""
        while True:
            with self._outbox_filled:
                while not self._outbox:
                    self._outbox_filled.wait()
                message, _ = self._outbox.popleft()
            try:
                self._connection.send(None if message is _END else message)
            except (OSError, ValueError):  # broken pipe: the process is gone
                pass
            if message is _END:
                return

    def _read_loop(self) -> None:
        watched = [self._connection] + ([self._partner.sentinel] if self._partner is not None else [])
        while True:
            if self._connection not in wait(watched):  # the partner ended
                watched.remove(self._partner.sentinel)
                if not self._closing:  # the pair dies together: the supervisor starts a new pair
                    self._partner_died = True
                    self._process.kill()
                continue
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
            # a process's pipe closes a moment before it can be reaped: wait for its exit code
            dead = self._partner if self._partner_died else self._process
            dead.join(timeout=1.0)
            name = "vision" if self._partner_died else "estimator"
            self._events.on_exit(f"{name} process exited (code {dead.exitcode})")

    async def close(self, timeout: float = 30.0) -> None:
        """Let the message in progress finish, end the stream, then stop the process."""
        self._closing = True
        if self._pending is not None:
            self._events.on_dropped(self._pending)
            self._pending = None
        await asyncio.to_thread(self._stop, timeout)

    def _stop(self, timeout: float) -> None:
        with self._outbox_filled:
            self._outbox.append((_END, False))
            self._outbox_filled.notify()
        self._writer.join(timeout)
        self._finished.wait(timeout)
        for process in (self._process, self._partner):
            if process is None:
                continue
            process.join(timeout=5)
            if process.is_alive():
                process.kill()
                process.join()
        self._connection.close()
