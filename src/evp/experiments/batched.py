"""Experiments whose work is a batch of jobs: run through the batch engine (local processes or a
Dask cluster), then reported beside the paper's figures.

Such a module offers ``jobs(variant, quick) -> list[Job]`` and ``report(variant, outcomes, quick,
out) -> Report``; this writes ``report.md`` (the paper's table and ours, the plots, the command,
the settings and versions, failed and slowest jobs) and ``results.json`` (per row: our figures,
the paper's, whether ours are ahead). The jobs' own files (``batch/``) make a rerun resume."""

from __future__ import annotations

import json
import platform
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

from evp.batch.jobs import Outcome
from evp.batch.runner import run_batch, summary_markdown


@dataclass
class Row:
    """One row of a paper's table: our figures, the paper's, and whether ours are ahead (None when
    the paper's method is not a baseline to beat, or a figure is missing)."""

    name: str
    ours: dict
    paper: dict
    ahead: bool | None = None


@dataclass
class Report:
    title: str
    body: list[str]  # Markdown: what was done, the tables, the plots
    rows: list[Row] = field(default_factory=list)
    settings: dict = field(default_factory=dict)


def versions() -> dict[str, str]:
    import cv2
    import numpy
    import scipy

    from evp import __version__

    return {"evp": __version__, "python": platform.python_version(), "numpy": numpy.__version__, "scipy": scipy.__version__, "opencv": cv2.__version__}


def run_experiment(module, variant: str | None, out: Path, executor, quick: bool, command: str, progress: Callable[[str], None]) -> Path:
    out.mkdir(parents=True, exist_ok=True)
    jobs = module.jobs(variant, quick)
    batch = run_batch(jobs, out / "batch", executor, progress)
    outcomes: dict[str, Outcome] = batch.outcomes
    progress("writing the report")
    report = module.report(variant, outcomes, quick, out)
    lines = [
        f"# {report.title}",
        "",
        f"Command: `{command}`" + (" (quick: a reduced run; the full one drops --quick)" if quick else ""),
        "",
        *report.body,
        "",
        "## Settings and versions",
        "",
        "```",
        json.dumps({"quick": quick, **report.settings, "versions": versions()}, indent=1, default=str),
        "```",
        "",
        "## Jobs",
        "",
        summary_markdown(batch),
    ]
    (out / "report.md").write_text("\n".join(lines))
    write_results(out, report.title, command, quick, report.rows, failed_jobs={o.key: o.error for o in batch.failed})
    return out / "report.md"


def write_results(out: Path, title: str, command: str, quick: bool, rows: list[Row], **extra) -> Path:
    """``results.json``: per row our figures, the paper's and whether ours are ahead."""
    results = {
        "experiment": title,
        "command": command,
        "quick": quick,
        "rows": [{"row": r.name, "ours": r.ours, "paper": r.paper, "ahead": r.ahead} for r in rows],
        **extra,
        "versions": versions(),
    }
    path = out / "results.json"
    path.write_text(json.dumps(results, indent=1, default=float))
    return path


def markdown_table(header: list[str], rows: list[list[str]]) -> list[str]:
    return [f"| {' | '.join(header)} |", "|" + "---|" * len(header), *[f"| {' | '.join(row)} |" for row in rows]]


def figure(value, digits: int = 2) -> str:
    """A number for a table; '-' when missing (a failed job, a figure the paper does not give)."""
    return "-" if value is None else f"{value:.{digits}f}"
