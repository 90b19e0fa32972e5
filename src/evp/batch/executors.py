"""Where jobs run: fresh local processes (the default) or a Dask cluster (``--cluster ADDRESS``).

Both offer the same three calls to the runner: ``capacity`` (jobs worth keeping in flight),
``start(job)`` and ``finished(timeout)`` (the outcomes that came in, possibly none). A job's
failure, however it happens (an exception, a worker process killed, a lost scheduler), comes back
as a failed outcome for that job alone.

Locally each job gets its own forked process, so a job that crashes its interpreter (a segfault in
native code, the kernel's OOM killer) is pinned on exactly that job, and no state leaks from one
job to the next; a fork costs milliseconds against jobs that render and run SLAM for minutes, and
the task's module is imported once, before the first fork, so the jobs do not each import it."""

from __future__ import annotations

import importlib
import multiprocessing
import sys
import time
import traceback
import uuid
from multiprocessing.connection import Connection, wait

from evp.batch.jobs import Job, Outcome
from evp.errors import LinkError, UsageError


def execute(job: Job) -> tuple[dict, float]:
    """Run ``job`` here: its record and its wall time (what a worker, local or remote, calls)."""
    module, _, function = job.task.partition(":")
    start = time.perf_counter()
    record = getattr(importlib.import_module(module), function)(**job.params)
    return record, time.perf_counter() - start


def error_text(exc: BaseException) -> str:
    return f"{type(exc).__name__}: {exc}".strip().rstrip(":")


def _child(job: Job, conn: Connection) -> None:
    try:
        record, wall = execute(job)
        conn.send(("ok", record, wall))
    except BaseException as exc:  # everything, KeyboardInterrupt included, is this job's failure
        last = traceback.extract_tb(exc.__traceback__)[-1:] if exc.__traceback__ else []
        where = f" (at {last[0].filename}:{last[0].lineno})" if last else ""
        conn.send(("error", error_text(exc) + where, 0.0))
    finally:
        conn.close()


class LocalProcesses:
    """Up to ``workers`` jobs at once, each in a new process of this interpreter."""

    def __init__(self, workers: int):
        if workers < 1:
            raise UsageError(f"--workers {workers}: at least 1")
        self.capacity = workers
        method = "fork" if sys.platform.startswith("linux") else "spawn"
        self._context = multiprocessing.get_context(method)
        self._running: dict[Connection, tuple[Job, multiprocessing.process.BaseProcess, float]] = {}

    def describe(self) -> str:
        return f"{self.capacity} local worker process{'es' if self.capacity != 1 else ''}"

    def start(self, job: Job) -> None:
        # the task's module (and what it imports) loaded once here, so each forked job starts warm:
        # importing the simulator and the pipeline costs a second or more per process
        importlib.import_module(job.task.partition(":")[0])
        receive, send = self._context.Pipe(duplex=False)
        process = self._context.Process(target=_child, args=(job, send), name=f"evp-job-{job.key}", daemon=True)
        process.start()
        send.close()  # the child holds the only writer: its death closes the pipe
        self._running[receive] = (job, process, time.perf_counter())

    def finished(self, timeout: float) -> list[Outcome]:
        if not self._running:
            return []
        outcomes = []
        for conn in wait(list(self._running), timeout):
            job, process, started = self._running.pop(conn)
            try:
                status, payload, wall = conn.recv()
            except (EOFError, OSError):
                process.join()
                status, payload, wall = "error", f"worker process died (exit code {process.exitcode})", time.perf_counter() - started
            conn.close()
            process.join()
            outcomes.append(
                Outcome(job.key, True, wall, payload) if status == "ok" else Outcome(job.key, False, wall or time.perf_counter() - started, error=payload)
            )
        return outcomes

    def close(self) -> None:
        for conn, (_, process, _) in self._running.items():
            process.terminate()
            process.join()
            conn.close()
        self._running.clear()


class DaskCluster:
    """Jobs on the Dask scheduler at ``address`` (``tcp://host:8786``); its workers must import
    ``evp`` (the same version) and see the datasets at the same paths."""

    def __init__(self, address: str, connect_timeout_s: float = 10.0):
        from distributed import Client

        try:
            self.client = Client(address, timeout=connect_timeout_s, set_as_default=False)
        except (OSError, TimeoutError) as exc:
            raise LinkError(f"could not reach the Dask scheduler at {address}: {error_text(exc)}") from exc
        self.address = address
        self._running: dict = {}
        self.capacity = self._threads()

    def _threads(self) -> int:
        """The cluster's worker threads now (workers come and go: read again after each outcome)."""
        return max(1, sum(self.client.nthreads().values()))

    def describe(self) -> str:
        workers = self.client.nthreads()
        return f"Dask scheduler {self.address} ({len(workers)} workers, {sum(workers.values())} threads)"

    def start(self, job: Job) -> None:
        future = self.client.submit(execute, job, key=f"evp-{job.key}-{uuid.uuid4().hex[:8]}", pure=False)
        self._running[future] = (job, time.perf_counter())

    def finished(self, timeout: float) -> list[Outcome]:
        from distributed import wait as dask_wait

        if not self._running:
            return []
        try:
            with self.client.as_current():
                done = dask_wait(list(self._running), timeout=timeout, return_when="FIRST_COMPLETED").done
        except TimeoutError:
            return []
        outcomes = []
        for future in done:
            job, started = self._running.pop(future)
            if future.status == "finished":
                record, wall = future.result()
                outcomes.append(Outcome(job.key, True, wall, record))
                continue
            if future.status == "error":
                exc = future.exception()
                text = error_text(exc)
                if type(exc).__name__ == "KilledWorker":
                    text = f"worker died while running the job ({text})"
            else:
                text = f"job {future.status} (lost the scheduler?)"
            outcomes.append(Outcome(job.key, False, time.perf_counter() - started, error=text))
            future.release()
        self.capacity = self._threads()
        return outcomes

    def close(self) -> None:
        for future in self._running:
            future.cancel()
        self._running.clear()
        self.client.close()


def make_executor(workers: int | None, cluster: str | None):
    """``--cluster ADDRESS`` when given, else ``--workers N`` local processes (default: 1)."""
    if workers is not None and cluster is not None:
        raise UsageError("give --workers N or --cluster ADDRESS, not both")
    if cluster is not None:
        return DaskCluster(cluster)
    return LocalProcesses(workers or 1)
