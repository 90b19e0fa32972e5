"""Experiments: the papers' studies reproduced as ``evp experiment NAME --out DIR``, each writing
a Markdown report (``report.md``) with its plots beside it.

An experiment is registered in :data:`EXPERIMENTS` by name with a one-line title and the module
that runs it; a module offers ``run(out: Path, progress: Callable[[str], None]) -> Path`` (the
report). Modules are imported only when their experiment runs, so listing stays fast."""

from __future__ import annotations

import importlib
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from evp.errors import UsageError


@dataclass(frozen=True)
class Experiment:
    name: str
    title: str
    module: str  # under evp.experiments

    def run(self, out: Path, progress: Callable[[str], None] = lambda text: None) -> Path:
        return importlib.import_module(f"evp.experiments.{self.module}").run(out, progress)


EXPERIMENTS = {
    e.name: e
    for e in (
        Experiment(
            "seed001-convergence",
            "Seed 001, Figures 9-12: EKF-SLAM convergence from true, wrong robot, wrong feature and all-wrong initial states",
            "seed001_convergence",
        ),
        Experiment(
            "seed001-dead-reckoning",
            "Seed 001, Figure 3: accelerometer double integration against wheel odometry (with and without the gyro) on the simulated robot",
            "seed001_dead_reckoning",
        ),
    )
}


def experiment(name: str) -> Experiment:
    if name not in EXPERIMENTS:
        raise UsageError(f"unknown experiment {name!r}; choose one of {', '.join(EXPERIMENTS)} (evp experiment list)")
    return EXPERIMENTS[name]
