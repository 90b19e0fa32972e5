"""``evp sweep``: ``evp run`` over datasets and a grid of settings, in parallel, into one table."""

from __future__ import annotations

from pathlib import Path

import typer

from evp.cli.progress import progress_line
from evp.io.output_paths import writable_folder

app = typer.Typer()


@app.command()
def sweep(
    datasets: list[Path] = typer.Argument(..., metavar="DATASETS...", help="Dataset folders or files (evp run reads them)."),
    sets: list[str] = typer.Option([], "--set", help="section.field=v1,v2,... (repeat for a grid; every combination runs)."),
    out: Path = typer.Option(..., "--out", help="Folder for results.csv/json, batch.md and jobs/ (a rerun skips the jobs done)."),
    config: Path | None = typer.Option(None, "--config", help="Settings YAML the --set values change."),
    workers: int | None = typer.Option(None, "--workers", min=1, help="Local worker processes (default 1)."),
    cluster: str | None = typer.Option(None, "--cluster", help="Dask scheduler address, e.g. tcp://10.0.0.5:8786."),
    keep_runs: bool = typer.Option(False, "--keep-runs", help="Also keep each run's folder (trajectory, plots) under OUT/runs/."),
) -> None:
    """Run every dataset with every combination of --set values; one row a run in OUT/results.csv."""
    from evp.batch.executors import make_executor
    from evp.batch.runner import run_batch, summary_markdown
    from evp.batch.sweep import sweep_jobs
    from evp.config import load_settings, with_overrides
    from evp.errors import DatasetError

    writable_folder(out)
    for path in datasets:
        if not path.exists():
            raise DatasetError(path, "not found")
    jobs = sweep_jobs(datasets, sets, config, out / "runs" if keep_runs else None)
    base = load_settings(config)
    for job in jobs:
        with_overrides(base, job.params["overrides"])  # a typo fails here, before any job starts
    result = run_batch(jobs, out, make_executor(workers, cluster), progress_line)
    typer.echo(summary_markdown(result))
    typer.echo(f"table in {out / 'results.csv'}")
