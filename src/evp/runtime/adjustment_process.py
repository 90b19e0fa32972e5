"""Bundle adjustments (and a loop's pose graph) solved in a helper process, for live mapping.

Python runs one thread at a time: a local bundle adjustment in the mapping thread (hundreds of
small NumPy calls per window) keeps taking the interpreter from tracking, which then misses
frames. In its own process the solve runs beside tracking on the second core; the problem and the
solution travel as a few hundred kB of arrays. Tracking's stop request (ORB-SLAM's InterruptBA)
reaches the helper through a process-shared event.
"""

from __future__ import annotations

import logging
import multiprocessing
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from typing import TYPE_CHECKING

import numpy as np

from evp.optim.bundle_adjustment import BundleProblem, bundle_adjust
from evp.optim.levenberg_marquardt import StopFlag
from evp.slam.adjustment import InlineAdjustment

if TYPE_CHECKING:
    from evp.geometry.sim3 import Sim3
    from evp.slam.loop_closing import GraphCorrection

log = logging.getLogger(__name__)

# In the helper process only: the stop event it was started with. A process-shared event cannot
# travel with each task, only be inherited at the start (the pool's initializer sets this).
_helper_stop: StopFlag | None = None


def _start_helper(stop: StopFlag) -> None:
    global _helper_stop
    _helper_stop = stop


def _solve_in_helper(problem: BundleProblem, evaluations: int, interruptible: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    return bundle_adjust(problem, evaluations, stop=_helper_stop if interruptible else None)


class AdjustmentProcess(InlineAdjustment):
    """The core's adjustments solved in one helper process; ``solve`` blocks the calling (mapping)
    thread, not the interpreter.

    forkserver, not fork: the parent already runs threads (tracking, mapping, OpenBLAS), which a
    forked child would inherit in whatever state they were. Should the helper die (killed for
    memory), solves fall back to the calling thread with a warning: mapping goes on, slower."""

    def __init__(self) -> None:
        context = multiprocessing.get_context("forkserver")
        super().__init__(context.Event())
        self._pool: ProcessPoolExecutor | None = ProcessPoolExecutor(1, mp_context=context, initializer=_start_helper, initargs=(self.stop,))
        # wait for the helper (its imports take ~2 s of CPU): started during a live run, it would
        # take that from tracking just when the map is being built
        try:
            self._pool.submit(int).result(timeout=120)
        except Exception as exc:  # noqa: BLE001 - e.g. a daemonic process may not have children
            log.warning("no bundle adjustment helper process (%s); adjusting in the mapping thread", exc)
            self._pool.shutdown(wait=False, cancel_futures=True)
            self._pool = None

    def solve(self, problem: BundleProblem, evaluations: int, interruptible: bool = True) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        if interruptible:
            self.stop.clear()
        return self._in_helper(_solve_in_helper, lambda: InlineAdjustment.solve(self, problem, evaluations, interruptible), problem, evaluations, interruptible)

    def solve_graph(self, graph: GraphCorrection) -> Sim3:
        return self._in_helper(graph.solve, graph.solve)

    def _in_helper(self, function: Callable, here: Callable, *args):
        """``function(*args)`` in the helper; ``here()`` in this thread once the helper is gone."""
        if self._pool is not None:
            try:
                return self._pool.submit(function, *args).result()
            except BrokenProcessPool:
                log.warning("the bundle adjustment helper process died; adjusting in the mapping thread from now on")
                self._pool = None
        return here()

    def close(self) -> None:
        """Stop the helper process (idempotent)."""
        if self._pool is not None:
            self._pool.shutdown(wait=True, cancel_futures=True)
            self._pool = None
