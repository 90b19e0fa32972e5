"""Jobs as plain records: what a batch runs, a settings grid expanded into jobs, and the outcome of
each, with the figures the progress line and the report need. No processes or files here."""

from __future__ import annotations

import hashlib
import itertools
import json
import re
from dataclasses import dataclass, field
from typing import Any

import yaml

from evp.errors import UsageError

KEY_PATTERN = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.=,+-]*$")


@dataclass(frozen=True)
class Job:
    """One unit of work: ``task`` ("module:function") called with ``params`` (JSON-ready) returns a
    JSON-ready record of figures. ``key`` names the job in the output folder and the table; it is
    stable across reruns, which is what makes a batch resumable."""

    key: str
    task: str
    params: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if not KEY_PATTERN.match(self.key) or len(self.key) > 120:
            raise UsageError(f"job key {self.key!r}: use letters, digits and _.=,+- (at most 120), it names a folder")
        if ":" not in self.task:
            raise UsageError(f"job {self.key}: task {self.task!r} must be 'module:function'")

    def fingerprint(self) -> str:
        """A digest of what the job computes: a stored result is reused only when it matches."""
        text = json.dumps({"task": self.task, "params": self.params}, sort_keys=True, default=str)
        return hashlib.sha256(text.encode()).hexdigest()[:16]


@dataclass
class Outcome:
    """What became of a job: ``ok`` with its record, or failed with the error's one-line text."""

    key: str
    ok: bool
    wall_s: float
    record: dict[str, Any] = field(default_factory=dict)
    error: str = ""
    reused: bool = False  # read back from an earlier run of the batch


def parse_set(text: str) -> tuple[str, list[Any]]:
    """``section.field=v1,v2,...`` as (``section.field``, values), each value read as YAML so
    numbers, booleans and lists keep their type ("[1,2]" stays one list value)."""
    name, sep, values = text.partition("=")
    if not sep or not name.strip() or not values.strip():
        raise UsageError(f"--set {text!r}: write section.field=value[,value...], e.g. --set orb.n_features=500,1000")
    parts = [values] if values.strip().startswith("[") else values.split(",")
    try:
        return name.strip(), [yaml.safe_load(part) for part in parts]
    except yaml.YAMLError as exc:
        raise UsageError(f"--set {text!r}: a value is not readable: {exc}") from exc


def settings_grid(sets: list[str]) -> list[dict[str, Any]]:
    """Every combination of the ``--set`` values, as dotted-name overrides (one empty dict when none)."""
    parsed = [parse_set(text) for text in sets]
    names = [name for name, _ in parsed]
    if len(set(names)) != len(names):
        raise UsageError(f"--set names a setting twice: {', '.join(sorted({n for n in names if names.count(n) > 1}))}")
    return [dict(zip(names, combination)) for combination in itertools.product(*(values for _, values in parsed))]


def overrides_label(overrides: dict[str, Any]) -> str:
    """A short, folder-safe label of a settings combination ("orb.n_features=500,slam.x=2")."""
    text = (
        ",".join(f"{name}={value if isinstance(value, str) else json.dumps(value, separators=(',', ':'))}" for name, value in overrides.items()) or "defaults"
    )
    return re.sub(r"[^A-Za-z0-9_.=,+-]", "_", text)


def slowest(outcomes: list[Outcome], count: int = 5) -> list[Outcome]:
    """The jobs that took longest (those computed in this run or an earlier one alike)."""
    return sorted(outcomes, key=lambda o: o.wall_s, reverse=True)[:count]


@dataclass(frozen=True)
class Progress:
    """The batch's state at one moment: how many jobs are done, running, failed and still waiting,
    and the time left estimated from the mean time of the jobs computed so far, less the time the
    running ones have already had (``running_elapsed_s``, summed)."""

    total: int
    done: int
    failed: int
    running: int
    elapsed_s: float
    mean_job_s: float | None
    workers: int
    running_elapsed_s: float = 0.0

    @property
    def waiting(self) -> int:
        return self.total - self.done - self.failed - self.running

    def time_left_s(self) -> float | None:
        if self.mean_job_s is None:
            return None
        spent = min(self.running_elapsed_s, self.mean_job_s * self.running)  # a job past the mean is counted as about to end
        return (self.mean_job_s * (self.waiting + self.running) - spent) / max(1, self.workers)

    def line(self) -> str:
        """One self-contained line (no cursor control), readable on a terminal and in a log."""
        left = self.time_left_s()
        eta = "time left unknown" if left is None else f"~{format_duration(left)} left"
        return f"{self.done + self.failed}/{self.total} finished ({self.done} ok, {self.failed} failed), {self.running} running, {self.waiting} waiting, {format_duration(self.elapsed_s)} elapsed, {eta}"


def format_duration(seconds: float) -> str:
    seconds = max(0.0, seconds)
    if seconds < 60:
        return f"{seconds:.0f}s"
    if seconds < 3600:
        return f"{int(seconds // 60)}m{int(seconds % 60):02d}s"
    return f"{int(seconds // 3600)}h{int(seconds % 3600 // 60):02d}m"
