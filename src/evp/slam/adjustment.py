"""Local mapping's bundle adjustments and a loop's pose graph, solved in the calling thread (the
core's default; evp.runtime solves them in a helper process for live mapping), and the stop
request by which tracking cuts a local window short (ORB-SLAM's InterruptBA)."""

from __future__ import annotations

from typing import TYPE_CHECKING, Protocol

import numpy as np

from evp.optim.bundle_adjustment import BundleProblem, bundle_adjust
from evp.optim.levenberg_marquardt import StopFlag

if TYPE_CHECKING:
    from evp.geometry.sim3 import Sim3
    from evp.slam.loop_closing import GraphCorrection


class StopRequest:
    """A stop flag for solves in the thread that raises it (inline mapping: a plain bool)."""

    def __init__(self) -> None:
        self._raised = False

    def set(self) -> None:
        self._raised = True

    def clear(self) -> None:
        self._raised = False

    def is_set(self) -> bool:
        return self._raised


class ResettableStop(StopFlag, Protocol):
    """What :class:`InlineAdjustment` needs of its stop flag: raised by ``interrupt``, lowered
    before each interruptible solve (a :class:`StopRequest`, or the runtime's process-shared event)."""

    def set(self) -> None: ...

    def clear(self) -> None: ...


class InlineAdjustment:
    """Bundle adjustments solved in the calling thread (inline mapping, tests, replays)."""

    def __init__(self, stop: ResettableStop | None = None) -> None:
        self.stop = stop if stop is not None else StopRequest()

    def solve(self, problem: BundleProblem, evaluations: int, interruptible: bool = True) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Poses, points and chi-square errors; ``interruptible`` solves (local windows) end early
        on :meth:`interrupt`, a global adjustment after a loop does not."""
        if interruptible:
            self.stop.clear()
        return bundle_adjust(problem, evaluations, stop=self.stop if interruptible else None)

    def solve_graph(self, graph: GraphCorrection) -> Sim3:
        """A loop's pose graph, optimised (the caller holds no lock: tracking goes on)."""
        return graph.solve()

    def interrupt(self) -> None:
        self.stop.set()

    def close(self) -> None:
        """Nothing to release."""
