"""The jobs of ``evp sweep``: every dataset with every combination of the ``--set`` values."""

from __future__ import annotations

import hashlib
from pathlib import Path

from evp.batch.jobs import Job, overrides_label, settings_grid

TASK = "evp.batch.tasks:run_dataset"


def sweep_jobs(datasets: list[Path], sets: list[str], config: Path | None = None, runs: Path | None = None) -> list[Job]:
    """One job a (dataset, settings) pair, keyed by the dataset's folder name and the settings
    (a digest replaces a key too long for a file name); ``runs``: where each run keeps its files."""
    names = [path.resolve().name for path in datasets]
    jobs = []
    for path, name in zip(datasets, names):
        if names.count(name) > 1:  # two datasets of one name (a/mav0, b/mav0): the parent names them apart
            name = f"{path.resolve().parent.name}-{name}"
        for overrides in settings_grid(sets):
            key = f"{name}.{overrides_label(overrides)}"
            if len(key) > 120:
                key = f"{name[:60]}.{hashlib.sha256(key.encode()).hexdigest()[:12]}"
            params = {"dataset": str(path.resolve()), "overrides": overrides, "config": str(config.resolve()) if config else None}
            if runs is not None:
                params["out"] = str((runs / key).resolve())
            jobs.append(Job(key, TASK, params))
    return jobs
