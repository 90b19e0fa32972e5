"""What runs the SLAM engine's work besides tracking: the map lock, local mapping's schedule and
a way to run independent callables at once. The core's :class:`InlineScheduler` runs everything
in the caller's thread, in order (deterministic: offline runs, tests, replays); evp.runtime lends
threads, a helper process and a real lock (live runs)."""

from __future__ import annotations

from collections.abc import Callable
from contextlib import AbstractContextManager, nullcontext
from typing import Protocol

from evp.slam.local_mapping import InlineMapping, LocalMapper, Mapping


class Scheduler(Protocol):
    map_lock: AbstractContextManager  # held by tracking per frame and by mapping per step
    # runs the callables it is given at once and returns their results in order (ORB's pyramid
    # levels, two-view initialisation's two models); None: one after another in the caller's thread
    parallel: Callable[..., list] | None

    def start_mapping(self, mapper: LocalMapper) -> Mapping:
        """Local mapping scheduled beside tracking."""
        ...

    def close(self) -> None:
        """Release what was started (threads, processes); idempotent."""
        ...


class InlineScheduler:
    """Nothing beside tracking: no lock to take, mapping in the tracking thread, no helpers."""

    map_lock = nullcontext()
    parallel = None

    def start_mapping(self, mapper: LocalMapper) -> Mapping:
        return InlineMapping(mapper)

    def close(self) -> None:
        """Nothing was started."""
