"""Machine-readable bench results: what bench/report.py renders into bench/README.md.

Each bench keeps its figures in ``bench/results/<bench>.json``: one or more tables, each a list of
columns (a heading and a ``str.format`` template over a record's fields) and of records (the
numbers, unformatted), and the runs that produced them (command, machine, date, git commit,
library versions). A new run replaces the records it measures again (same key fields) and keeps
the others, so ``--only`` runs update their own rows; a run none of whose records is left is
dropped. The file is written after every row, so an interrupted bench keeps what it measured.
The same columns print the bench's Markdown table, so stdout and bench/README.md agree.
"""

from __future__ import annotations

import datetime
import json
import os
import platform
import string
import subprocess
from collections.abc import Sequence
from pathlib import Path

RESULTS = Path(__file__).resolve().parent / "results"
MISSING = "-"


def markdown_header(columns: Sequence[tuple[str, str]]) -> str:
    return f"| {' | '.join(heading for heading, _ in columns)} |\n" + "|---" * len(columns) + "|"


def markdown_cell(template: str, record: dict) -> str:
    """``template`` filled from ``record``; ``MISSING`` when a field it names is absent or None."""
    fields = [name for _, name, _, _ in string.Formatter().parse(template) if name]
    if any(record.get(name) is None for name in fields):
        return MISSING
    return template.format(**record)


def markdown_row(columns: Sequence[tuple[str, str]], record: dict) -> str:
    return f"| {' | '.join(markdown_cell(template, record) for _, template in columns)} |"


def _git(*args: str) -> str:
    try:
        return subprocess.run(["git", *args], cwd=RESULTS.parent, capture_output=True, text=True, check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return ""


def _versions() -> dict[str, str]:
    import cv2
    import numpy
    import scipy

    return {"python": platform.python_version(), "numpy": numpy.__version__, "scipy": scipy.__version__, "opencv": cv2.__version__}


def current_run(command: str) -> dict:
    """The provenance of a run started now: the command, this machine, the date and the commit
    (``-dirty`` when tracked files differ from it)."""
    commit = _git("rev-parse", "--short", "HEAD") or "unknown"
    if _git("status", "--porcelain", "--untracked-files=no"):
        commit += "-dirty"
    return {
        "command": command,
        "machine": f"{platform.node()}, {platform.machine()}, {os.cpu_count()} cores",
        "date": datetime.datetime.now(datetime.UTC).strftime("%Y-%m-%d %H:%M UTC"),
        "commit": commit,
        "versions": _versions(),
    }


class Results:
    """The results file of one bench, updated as rows come in."""

    def __init__(self, bench: str, command: str, path: Path | None = None):
        self.path = path or RESULTS / f"{bench}.json"
        self.data = json.loads(self.path.read_text()) if self.path.exists() else {"bench": bench, "runs": [], "tables": []}
        self.run = current_run(command)
        self._run_index: int | None = None

    def table(self, name: str, columns: Sequence[tuple[str, str]], key: Sequence[str], caption: str = "") -> Table:
        """Table ``name`` (created, or its columns and caption replaced); rows with equal ``key``
        fields replace each other."""
        existing = next((t for t in self.data["tables"] if t["name"] == name), None)
        if existing is None:
            existing = {"name": name, "records": []}
            self.data["tables"].append(existing)
        existing.update(columns=[list(c) for c in columns], key=list(key), caption=caption)
        return Table(self, existing)

    def note(self, text: str) -> None:
        """A line printed under the tables for this run (e.g. a summary over its rows)."""
        self.data["runs"][self.run_index()]["note"] = text
        self.save()

    def run_index(self) -> int:
        """This run's place in the file's runs (it is added with its first record or note)."""
        if self._run_index is None:
            self.data["runs"].append(self.run)
            self._run_index = len(self.data["runs"]) - 1
        return self._run_index

    def save(self) -> None:
        used = sorted({r["run"] for t in self.data["tables"] for r in t["records"]} | ({self._run_index} if self._run_index is not None else set()))
        renumber = {old: new for new, old in enumerate(used)}
        self.data["runs"] = [self.data["runs"][old] for old in used]
        for table in self.data["tables"]:
            for record in table["records"]:
                record["run"] = renumber[record["run"]]
        if self._run_index is not None:
            self._run_index = renumber[self._run_index]
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.path.write_text(json.dumps(self.data, indent=1) + "\n")


class Table:
    def __init__(self, results: Results, data: dict):
        self.results = results
        self.data = data

    @property
    def columns(self) -> list[tuple[str, str]]:
        return [tuple(c) for c in self.data["columns"]]

    def header(self) -> str:
        return markdown_header(self.columns)

    def add(self, record: dict) -> str:
        """Store ``record`` (in the place of one with the same key, else last) and return its
        Markdown row."""
        stored = {**record, "run": self.results.run_index()}
        records = self.data["records"]
        same = [i for i, r in enumerate(records) if all(r.get(k) == record.get(k) for k in self.data["key"])]
        if same:
            records[same[0]] = stored
        else:
            records.append(stored)
        self.results.save()
        return markdown_row(self.columns, record)
