"""Local mapping in its own thread, fed by a keyframe queue (live runs): tracking goes on while
the core's LocalMapper maps each keyframe (its insert and refine steps, under the map lock per
step)."""

from __future__ import annotations

import queue
import threading
import time

from evp.slam.adjustment import InlineAdjustment
from evp.slam.local_mapping import LocalMapper, NewKeyFrame


def _yield_to_tracking() -> None:
    """Called after each step the mapper takes under the map lock: Python's locks are not fair,
    and tracking may be waiting for it."""
    time.sleep(0)


class MappingWorker:
    """A :class:`~evp.slam.local_mapping.Mapping` in a thread of its own; ``idle`` tells tracking
    whether to insert keyframes. ``adjuster`` solves the mapper's bundle adjustments (the runtime
    gives its helper process)."""

    def __init__(self, mapper: LocalMapper, adjuster: InlineAdjustment):
        self.mapper = mapper
        self.queue: queue.Queue[NewKeyFrame | None] = queue.Queue()
        mapper.adjuster = adjuster
        mapper.keyframes_waiting = lambda: not self.queue.empty()
        mapper.step_done = _yield_to_tracking
        self.mapping_ms: list[float] = []
        self.max_queue = 0
        self.error: BaseException | None = None
        self._busy = threading.Event()
        self._thread = threading.Thread(target=self._run, name="evp-local-mapping", daemon=True)
        self._thread.start()

    @property
    def idle(self) -> bool:
        return self.queue.empty() and not self._busy.is_set()

    @property
    def pending(self) -> int:
        """Keyframes waiting in the queue (not counting the one being processed)."""
        return self.queue.qsize()

    def interrupt(self) -> None:
        """Tracking needs a keyframe: cut the running bundle adjustment short (ORB-SLAM's InterruptBA)."""
        self.mapper.adjuster.interrupt()

    def submit(self, item: NewKeyFrame) -> None:
        self._busy.set()
        self.queue.put(item)
        self.max_queue = max(self.max_queue, self.queue.qsize())

    def _run(self) -> None:
        while True:
            item = self.queue.get()
            if item is None:
                self._busy.clear()
                return
            self._busy.set()
            start = time.perf_counter()
            try:
                self.mapper.process(item)
            except Exception as exc:  # surfaced to the caller by finish(); the thread must not die silently
                self.error = exc
            self.mapping_ms.append((time.perf_counter() - start) * 1000.0)
            if self.queue.empty():
                self._busy.clear()

    def settle(self) -> None:
        """Nothing to wait for: the thread maps keyframes as they come."""

    def finish(self) -> None:
        """Map every keyframe queued, stop the thread and the adjuster; raise what mapping raised."""
        self._stop()
        error, self.error = self.error, None
        if error is not None:
            raise error

    def close(self) -> None:
        """Stop now (a run that failed): keyframes still queued are dropped, a running local
        bundle adjustment is cut short. Idempotent."""
        while True:
            try:
                self.queue.get_nowait()
            except queue.Empty:
                break
        self.interrupt()
        self._stop()

    def _stop(self) -> None:
        if self._thread.is_alive():
            self.queue.put(None)
            self._thread.join()
        self.mapper.adjuster.close()
