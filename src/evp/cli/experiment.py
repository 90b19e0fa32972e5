"""``evp experiment``: the papers' studies, each writing a Markdown report with plots."""

from __future__ import annotations

import shlex
import sys
from pathlib import Path

import typer

from evp.errors import UsageError
from evp.io.output_paths import writable_folder

app = typer.Typer()


@app.command()
def experiment(
    name: str = typer.Argument(..., help="An experiment's name, or 'list' to print them."),
    out: Path | None = typer.Option(None, "--out", help="Folder for report.md, results.json and the plots (a rerun resumes the jobs done)."),
    quick: bool = typer.Option(False, "--quick", help="A reduced run: short renders, few flights and seeds (minutes, not hours)."),
    workers: int | None = typer.Option(None, "--workers", min=1, help="Local worker processes for the experiment's jobs (default 1)."),
    cluster: str | None = typer.Option(None, "--cluster", help="Dask scheduler address to run the jobs on, e.g. tcp://10.0.0.5:8786."),
    verbose: bool = typer.Option(False, "--verbose", help="With list: the titles too."),
) -> None:
    """Run one of the papers' studies (evp experiment list names them, one a line)."""
    from evp.cli.progress import progress_line
    from evp.experiments import EXPERIMENTS
    from evp.experiments import experiment as find

    if name == "list":
        for item in EXPERIMENTS.values():
            typer.echo(f"{item.name:24s} {item.title}" if verbose else item.name)
        return
    chosen = find(name)
    if out is None:
        raise UsageError("give --out DIR for the report")
    writable_folder(out)
    from evp.batch.executors import make_executor

    command = "evp " + " ".join(shlex.quote(arg) for arg in sys.argv[1:])
    report = chosen.run(out, lambda text: progress_line(f"{name}: {text}"), quick, make_executor(workers, cluster), command)
    typer.echo(f"{name}: report in {report}")
