"""A long-lived helper thread for the callables the core runs at once (ORB's pyramid levels,
two-view initialisation's homography and fundamental matrix): OpenCV releases Python's
interpreter lock, so the caller's thread and the helper use two cores. One pool for the whole run,
not one per call (starting threads per frame or per initialisation attempt costs time)."""

from __future__ import annotations

from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor, wait
from typing import Any


class HelperThreads:
    def __init__(self, helpers: int = 1) -> None:
        self._pool = ThreadPoolExecutor(helpers, thread_name_prefix="evp-helper")

    def __call__(self, *tasks: Callable[[], Any]) -> list[Any]:
        """The tasks' results in order: the last runs in the calling thread, the others in the
        helpers. Every task has ended when this returns or raises (a task's error is raised)."""
        futures = [self._pool.submit(task) for task in tasks[:-1]]
        try:
            last = tasks[-1]()
        finally:
            wait(futures)  # no task may still be using what the caller shares with it
        return [future.result() for future in futures] + [last]

    def close(self) -> None:
        """Stop the helper threads (idempotent)."""
        self._pool.shutdown(wait=True)
