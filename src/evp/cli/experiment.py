"""``evp experiment``: the papers' studies, each writing a Markdown report with plots."""

from __future__ import annotations

from pathlib import Path

import typer

from evp.errors import UsageError
from evp.io.output_paths import writable_folder

app = typer.Typer()


@app.command()
def experiment(
    name: str = typer.Argument(..., help="An experiment's name, or 'list' to print them."),
    out: Path | None = typer.Option(None, "--out", help="Folder for report.md and its plots."),
) -> None:
    """Run one of the papers' studies (evp experiment list names them)."""
    from evp.experiments import EXPERIMENTS
    from evp.experiments import experiment as find

    if name == "list":
        for item in EXPERIMENTS.values():
            typer.echo(f"{item.name:24s} {item.title}")
        return
    chosen = find(name)
    if out is None:
        raise UsageError("give --out DIR for the report")
    writable_folder(out)
    report = chosen.run(out, lambda text: typer.echo(f"{name}: {text}", err=True))
    typer.echo(f"{name}: report in {report}")
