"""Run a list of jobs on an executor, storing each outcome as it arrives, and collect the table.

The output folder holds ``jobs/<key>.json`` per job (its parameters' fingerprint, the record or
the error, the wall time), written the moment the job comes back, so nothing computed is lost when
the batch, a worker or the scheduler stops; a rerun reads the successful ones back (when the job
still computes the same thing) and runs the rest, failed ones included. ``results.json`` and
``results.csv`` (one row a job) and ``batch.md`` (failures with their errors, the slowest jobs)
are written at the end."""

from __future__ import annotations

import csv
import json
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from evp.batch.jobs import Job, Outcome, Progress, format_duration, slowest
from evp.errors import UsageError

PROGRESS_EVERY_S = 10.0  # a progress line at least this often while jobs run, and at each outcome


@dataclass
class BatchResult:
    jobs: list[Job]
    outcomes: dict[str, Outcome]
    executor: str
    wall_s: float

    @property
    def failed(self) -> list[Outcome]:
        return [self.outcomes[j.key] for j in self.jobs if not self.outcomes[j.key].ok]

    def records(self) -> list[dict]:
        """One flat row a job: its key, status, time, error and the record's fields."""
        rows = []
        for job in self.jobs:
            outcome = self.outcomes[job.key]
            row = {"job": job.key, "status": "ok" if outcome.ok else "failed", "wall_s": round(outcome.wall_s, 3), "error": outcome.error}
            rows.append(row | {k: v for k, v in outcome.record.items() if not isinstance(v, list | dict)})
        return rows


def _job_file(out: Path, key: str) -> Path:
    return out / "jobs" / f"{key}.json"


def _stored(out: Path, job: Job) -> Outcome | None:
    """The successful outcome an earlier run stored for this very job, if any."""
    path = _job_file(out, job.key)
    try:
        data = json.loads(path.read_text())
    except (OSError, ValueError):
        return None  # absent, or cut short by a crash mid-write: run the job again
    if data.get("status") != "ok" or data.get("fingerprint") != job.fingerprint():
        return None
    return Outcome(job.key, True, float(data["wall_s"]), data["record"], reused=True)


def _store(out: Path, job: Job, outcome: Outcome) -> None:
    path = _job_file(out, job.key)
    data = {
        "job": job.key,
        "task": job.task,
        "params": job.params,
        "fingerprint": job.fingerprint(),
        "status": "ok" if outcome.ok else "failed",
        "wall_s": outcome.wall_s,
        "error": outcome.error,
        "record": outcome.record,
    }
    temporary = path.with_suffix(".part")
    temporary.write_text(json.dumps(data, indent=1, default=float))
    temporary.replace(path)  # a crash leaves the old file or the new one, never half of one


def run_batch(
    jobs: list[Job],
    out: Path,
    executor,
    progress: Callable[[str], None] = lambda line: None,
    clock: Callable[[], float] = time.monotonic,
) -> BatchResult:
    """Every job run (or read back) once; failures are outcomes, not exceptions."""
    keys = [job.key for job in jobs]
    if len(set(keys)) != len(keys):
        raise UsageError(f"two jobs share a key: {sorted({k for k in keys if keys.count(k) > 1})}")
    (out / "jobs").mkdir(parents=True, exist_ok=True)
    start = clock()
    outcomes: dict[str, Outcome] = {}
    for job in jobs:
        if (stored := _stored(out, job)) is not None:
            outcomes[job.key] = stored
    waiting = [job for job in jobs if job.key not in outcomes]
    where = executor.describe()
    if outcomes:
        progress(f"{len(outcomes)} of {len(jobs)} jobs already done in {out} (reused); {len(waiting)} to run on {where}")
    else:
        progress(f"{len(jobs)} jobs on {where}")
    by_key = {job.key: job for job in jobs}
    started: dict[str, float] = {}  # key -> when the job was handed to the executor
    computed = [o.wall_s for o in outcomes.values()]  # job times for the estimate of the time left, earlier runs' too
    last_line = clock()
    try:
        while waiting or started:
            while waiting and len(started) < executor.capacity:
                job = waiting.pop(0)
                executor.start(job)
                started[job.key] = clock()
            arrived = executor.finished(timeout=1.0)
            for outcome in arrived:
                del started[outcome.key]
                outcomes[outcome.key] = outcome
                _store(out, by_key[outcome.key], outcome)
                if outcome.ok:
                    computed.append(outcome.wall_s)
                    progress(f"{outcome.key}: ok in {format_duration(outcome.wall_s)}")
                else:
                    progress(f"{outcome.key}: FAILED after {format_duration(outcome.wall_s)}: {outcome.error}")
            if arrived or clock() - last_line >= PROGRESS_EVERY_S:
                progress(_progress(jobs, outcomes, started, clock(), start, computed, executor.capacity).line())
                last_line = clock()
    finally:
        executor.close()
    result = BatchResult(jobs, outcomes, where, clock() - start)
    write_tables(result, out)
    return result


def _progress(jobs, outcomes, started, now, start, computed, workers) -> Progress:
    done = sum(o.ok for o in outcomes.values())
    mean = sum(computed) / len(computed) if computed else None
    return Progress(len(jobs), done, len(outcomes) - done, len(started), now - start, mean, workers, sum(now - t for t in started.values()))


def summary_markdown(result: BatchResult, slowest_count: int = 5) -> str:
    """The batch in a few lines: counts, each failure with its error, the slowest jobs."""
    outcomes = [result.outcomes[job.key] for job in result.jobs]
    reused = sum(o.reused for o in outcomes)
    lines = [
        f"{len(outcomes)} jobs on {result.executor}: {sum(o.ok for o in outcomes)} ok ({reused} reused from an earlier run), "
        f"{len(result.failed)} failed; {format_duration(result.wall_s)} wall.",
        "",
    ]
    if result.failed:
        lines += ["| failed job | error |", "|---|---|", *[f"| {o.key} | {o.error.replace('|', '/')} |" for o in result.failed], ""]
    lines += [
        "| slowest jobs | wall time |",
        "|---|---|",
        *[f"| {o.key} | {format_duration(o.wall_s)}{' (earlier run)' if o.reused else ''} |" for o in slowest(outcomes, slowest_count)],
        "",
    ]
    return "\n".join(lines)


def write_tables(result: BatchResult, out: Path) -> None:
    rows = result.records()
    (out / "results.json").write_text(json.dumps(rows, indent=1, default=float))
    columns = list(dict.fromkeys(name for row in rows for name in row))
    with (out / "results.csv").open("w", newline="") as handle:
        writer = csv.DictWriter(handle, columns)
        writer.writeheader()
        writer.writerows(rows)
    (out / "batch.md").write_text(summary_markdown(result))
