"""The batch engine (``evp.batch``): speed-up with 1 and 2 workers, local processes against a
Dask cluster, and the scheduling overhead per job.

Usage: python bench/batch_engine.py [--workers 1 2] [--seeds 1] [--empty-jobs 40]

Two tables. Speed-up: the 14 cases of ``evp experiment seed002-spoofing`` (each a job of
``--seeds`` seeded flights of the GPS monitor, ~1-3 CPU seconds; a real workload, no rendering) on
N local worker processes and on a Dask LocalCluster of N single-threaded worker processes; the
speed-up is against 1 worker of the same kind, in the same run. Overhead: ``--empty-jobs`` jobs
that return at once, on 1 worker: the batch's wall time per job is what scheduling, process
start (local: a fork per job) or the round trip to the scheduler (Dask) costs. The machine's
load average is recorded beside each row: on a shared machine the speed-up says more about the
other users than about the engine. Needs dask and distributed (the ``cluster`` extra).
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

from results import Results

from evp.batch.executors import DaskCluster, LocalProcesses
from evp.batch.jobs import Job
from evp.batch.runner import run_batch
from evp.experiments import seed002_spoofing

SPEEDUP_COLUMNS = [
    ("cores", "{cores}"),
    ("executor", "{executor}"),
    ("workers", "{workers}"),
    ("jobs", "{jobs}"),
    ("seeds a job", "{seeds}"),
    ("wall s", "{wall_s:.1f}"),
    ("speed-up vs 1 worker", "{speedup:.2f}x"),
    ("load average (1 min) at start", "{load:.1f}"),
]
OVERHEAD_COLUMNS = [
    ("cores", "{cores}"),
    ("executor", "{executor}"),
    ("empty jobs", "{jobs}"),
    ("wall s", "{wall_s:.2f}"),
    ("per job (ms)", "{per_job_ms:.0f}"),
    ("load average", "{load:.1f}"),
]


def nothing() -> dict:
    """A job that does no work: what is left of its time is the engine's."""
    return {}


def timed_batch(jobs: list[Job], executor) -> float:
    with tempfile.TemporaryDirectory(prefix="evp-batch-bench-") as out:
        start = time.perf_counter()
        result = run_batch(jobs, Path(out), executor)
        wall = time.perf_counter() - start
    if result.failed:
        raise SystemExit(f"bench jobs failed: {[(o.key, o.error) for o in result.failed]}")
    return wall


def executors(workers: int):
    """(name, executor) for local processes, then for a Dask LocalCluster of ``workers`` (closed
    when the caller moves on)."""
    yield "local processes", LocalProcesses(workers)
    from distributed import LocalCluster

    with LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=None) as cluster:
        yield "Dask LocalCluster", DaskCluster(cluster.scheduler_address)


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--workers", nargs="*", type=int, default=[1, 2])
    parser.add_argument("--seeds", type=int, default=1)
    parser.add_argument("--empty-jobs", type=int, default=40)
    args = parser.parse_args()
    os.environ.setdefault("OMP_NUM_THREADS", "1")  # one core a worker: the workers are the parallelism
    cores = os.cpu_count()
    results = Results("batch_engine", "python bench/batch_engine.py " + " ".join(sys.argv[1:]))
    work = [Job(j.key, j.task, {**j.params, "seeds": args.seeds}) for j in seed002_spoofing.jobs(None, quick=True)]
    speedup = results.table(
        "speedup",
        SPEEDUP_COLUMNS,
        key=["cores", "executor", "workers", "seeds"],
        caption="seed002-spoofing's jobs on N workers, on machines of 2 and more cores",
    )
    print(speedup.header(), flush=True)
    single: dict[str, float] = {}
    for workers in sorted(args.workers):
        for name, executor in executors(workers):
            load = os.getloadavg()[0]
            wall = timed_batch(work, executor)
            single.setdefault(name, wall)
            print(
                speedup.add(
                    {
                        "cores": cores,
                        "seeds": args.seeds,
                        "executor": name,
                        "workers": workers,
                        "jobs": len(work),
                        "wall_s": wall,
                        "speedup": single[name] / wall,
                        "load": load,
                    }
                ),
                flush=True,
            )
    overhead = results.table("overhead", OVERHEAD_COLUMNS, key=["cores", "executor"], caption="jobs that return at once, 1 worker: the engine's cost per job")
    print(overhead.header(), flush=True)
    empty = [Job(f"empty{i}", "batch_engine:nothing") for i in range(args.empty_jobs)]
    for name, executor in executors(1):
        load = os.getloadavg()[0]
        wall = timed_batch(empty, executor)
        print(
            overhead.add({"cores": cores, "executor": name, "jobs": len(empty), "wall_s": wall, "per_job_ms": 1000 * wall / len(empty), "load": load}),
            flush=True,
        )


if __name__ == "__main__":
    main()
