"""The Levenberg-Marquardt loop shared by the bundle adjustment and the loop's pose graph: the
damping falls by 3 after a step that lowers the cost and rises by 4 until one does (Nielsen's
schedule, simplified), and the solve ends after ``iterations`` accepted steps, when no damping
gives a lower cost, or when the relative reduction falls under ``min_reduction``."""

from __future__ import annotations

from collections.abc import Callable
from typing import Protocol, TypeVar

INITIAL_DAMPING = 1e-4
MIN_DAMPING = 1e-9
MAX_DAMPING = 1e8  # no step lowers the cost even this close to gradient descent: converged or stuck

Estimate = TypeVar("Estimate")


class StopFlag(Protocol):
    """What the loop polls between iterations: anything with ``is_set`` (a plain flag in the
    solving thread, an event shared with another thread or process)."""

    def is_set(self) -> bool: ...


def levenberg_marquardt(
    start: Estimate,
    step: Callable[[Estimate, float], Estimate | None],
    cost: Callable[[Estimate], float],
    iterations: int,
    min_reduction: float,
    stop: StopFlag | None = None,
) -> Estimate:
    """The estimate the loop ends on. ``step(estimate, damping)`` is the next estimate (None when
    the damped system cannot be solved); ``stop``, when set, ends the solve before the next
    iteration (tracking interrupting a local window)."""
    current, current_cost, damping = start, cost(start), INITIAL_DAMPING
    for _ in range(iterations):
        if stop is not None and stop.is_set():
            break
        improved = False
        while damping < MAX_DAMPING:
            trial = step(current, damping)
            if trial is not None:
                trial_cost = cost(trial)
                if trial_cost < current_cost:
                    reduction = (current_cost - trial_cost) / max(current_cost, 1e-12)
                    current, current_cost, improved = trial, trial_cost, True
                    damping = max(damping / 3.0, MIN_DAMPING)
                    break
            damping *= 4.0
        if not improved or reduction < min_reduction:
            break
    return current
