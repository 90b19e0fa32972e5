"""Experiments: the papers' studies reproduced as ``evp experiment NAME --out DIR``, each writing
a Markdown report (``report.md``) with its plots beside it.

An experiment is registered in :data:`EXPERIMENTS` by name with a one-line title, the module that
runs it and the variant of that module's study it is (one module can serve several experiments).
A module offers either ``jobs``/``report`` (its work goes through the batch engine, see
:mod:`evp.experiments.batched`, which also writes ``results.json``) or
``run(out: Path, progress: Callable[[str], None]) -> Path`` (the report). Modules are imported
only when their experiment runs, so listing stays fast."""

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
    variant: str | None = None

    def run(self, out: Path, progress: Callable[[str], None] = lambda text: None, quick: bool = False, executor=None, command: str = "") -> Path:
        """The report's path; ``executor`` runs a batched experiment's jobs (default: one local process)."""
        from evp.experiments.batched import run_experiment, write_results

        module = importlib.import_module(f"evp.experiments.{self.module}")
        command = command or f"evp experiment {self.name} --out {out}"
        if hasattr(module, "jobs"):
            from evp.batch.executors import LocalProcesses

            return run_experiment(module, self.variant, out, executor or LocalProcesses(1), quick, command, progress)
        report = module.run(out, progress)  # runs in this process, the same with or without --quick
        write_results(out, self.title, command, quick, [], note="figures in report.md only (this study predates results.json rows)")
        return report


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
        Experiment(
            "seed000-indoor-circle",
            "Seed 000, indoor test (Figs 8-10): RMSE XY on the rendered 2.2 m circle, SLAM alone (Sim3) and with the navigation filter",
            "seed000_flights",
            "circle-indoor",
        ),
        Experiment(
            "seed000-football-field",
            "Seed 000, football field: RMSE XY over the low-texture field loops, SLAM alone (Sim3) and the navigation filter (metric, no alignment)",
            "seed000_flights",
            "drone-field-loops",
        ),
        Experiment(
            "seed000-textured-square",
            "Seed 000, textured square: RMSE XY over the paved-square loops, SLAM alone (Sim3) and the navigation filter (metric, no alignment)",
            "seed000_flights",
            "drone-square-loops",
        ),
        Experiment("seed002-table1", "Seed 002, Table I: the offline flights A-G rendered (duration, distance, target altitude)", "seed002_flights", "table1"),
        Experiment(
            "seed002-tables2-5",
            "Seed 002, Tables II-V: 2D+baro vs 3D+baro errors against GPS, whole flight and near the target altitude, with quartiles, IQR and std",
            "seed002_flights",
            "tables2-5",
        ),
        Experiment(
            "seed002-figs",
            "Seed 002, Figs 1-8: altitude 2D vs 3D, error histograms, box plots, the track with GPS uncertainty circles",
            "seed002_flights",
            "figs",
        ),
        Experiment(
            "seed002-spoofing",
            "Seed 002's spoofing idea: pull-offs and jumps of several sizes and GPS outages; detection delay and error growth",
            "seed002_spoofing",
        ),
        Experiment(
            "seed002-toledo",
            "Seed 002 on real data: the Toledo survey (47 nadir photos with GPS) aligned to GPS, errors on the held-out half",
            "seed002_toledo",
        ),
    )
}


def experiment(name: str) -> Experiment:
    if name not in EXPERIMENTS:
        raise UsageError(f"unknown experiment {name!r}; choose one of {', '.join(EXPERIMENTS)} (evp experiment list)")
    return EXPERIMENTS[name]
