"""Write bench/README.md: how to run each benchmark (from each script's module docstring) and the
current results (from bench/results/*.json, which the benches write as they run). The file is
never edited by hand; change a docstring or re-run a bench, then run this.

Usage: python bench/report.py [--run] [--check]

``--run`` first runs the quick benches (a few minutes in all; see ``QUICK``); the others take
from minutes to an hour each and are run one by one as their sections say. ``--check`` writes
nothing and exits 1 when bench/README.md is not what this would write.
"""

from __future__ import annotations

import argparse
import ast
import json
import subprocess
import sys
from pathlib import Path

from results import RESULTS, markdown_header, markdown_row

BENCH = Path(__file__).resolve().parent
README = BENCH / "README.md"
HELPERS = {"report.py", "results.py"}  # not benchmarks
QUICK = [["eval_vs_evo.py"], ["sim_speed.py", "--skip-flight"], ["gps_alignment.py", "--skip-rendered"], ["dropped_frames.py"]]
# the order of the sections: the main bench first, then the live ones, then the rest by name
FIRST = ["run_sequences", "realtime_replay", "live_replays", "mapping_lag", "long_flight", "dropped_frames", "station_latency", "live_navigation"]

INTRO = """\
# Benchmarks

<!-- Written by `python bench/report.py`; do not edit. The how-to comes from each script's
docstring, the figures from bench/results/*.json. -->

Accuracy and speed of EVP on the shared sequences (`../shared/data`) and on rendered flights.
They are not part of the test run. Install first with `bash scripts/setup.sh`: it installs the
exact versions of `constraints.txt`, the ones the figures below were measured with (an OpenCV
release has moved a figure before). Then run a bench with `.venv/bin/python bench/NAME.py`.

Each bench prints Markdown tables and records its rows, with the command, machine, date, git
commit and library versions of the run, in `bench/results/NAME.json`; a later run replaces the
rows it measures again. `python bench/report.py` rewrites this file from those records
(`--run` runs the quick benches first: {quick}). Timings depend on the machine and its load;
compare them only within one run (the ratio to OpenCV's ORB is timed in the same run for that
reason). Why the engine is built as it is, and what was tried and rejected, is in
[docs/decisions.md](../docs/decisions.md).
"""


def benches() -> list[str]:
    names = sorted(p.stem for p in BENCH.glob("*.py") if p.name not in HELPERS)
    return [n for n in FIRST if n in names] + [n for n in names if n not in FIRST]


def docstring(name: str) -> str:
    return ast.get_docstring(ast.parse((BENCH / f"{name}.py").read_text())) or ""


def markdown_from_docstring(text: str) -> str:
    """A docstring as Markdown: RST literals become code spans, ``Usage:`` lines code blocks."""
    text = text.replace("``", "`")
    out = []
    for paragraph in text.split("\n\n"):
        if paragraph.startswith("Usage:"):
            out.append("```\n" + paragraph.removeprefix("Usage:").strip() + "\n```")
        else:
            out.append(paragraph)
    return "\n\n".join(out)


def summary_line(name: str) -> str:
    return " ".join(docstring(name).split("\n\n")[0].split())


def render_results(name: str) -> str:
    path = RESULTS / f"{name}.json"
    if not path.exists():
        return "No results recorded yet.\n"
    data = json.loads(path.read_text())
    parts = []
    for table in data["tables"]:
        if not table["records"]:
            continue
        columns = [*[tuple(c) for c in table["columns"]], ("run", "{run_number}")]
        rows = [markdown_row(columns, {**r, "run_number": r["run"] + 1}) for r in table["records"]]
        caption = f"{table['caption']}:\n\n" if table.get("caption") else ""
        parts.append(caption + markdown_header(columns) + "\n" + "\n".join(rows) + "\n")
    runs = []
    for number, run in enumerate(data["runs"], 1):
        versions = ", ".join(f"{k} {v}" for k, v in run.get("versions", {}).items())
        line = f"{number}. `{run['command']}` ({run['machine']}; {run['date']}; commit {run['commit']}{'; ' + versions if versions else ''})"
        if run.get("note"):
            line += f"\n   {run['note']}"
        runs.append(line)
    return "\n".join(parts) + "\nRuns:\n\n" + "\n".join(runs) + "\n"


def render() -> str:
    names = benches()
    quick = ", ".join(f"`{' '.join(q)}`" for q in QUICK)
    sections = [INTRO.format(quick=quick), "## Contents\n\n" + "\n".join(f"- [{n}.py](#{n}py): {_first_sentence(summary_line(n))}" for n in names) + "\n"]
    for name in names:
        sections.append(f"## {name}.py\n\n{markdown_from_docstring(docstring(name))}\n\n### Results\n\n{render_results(name)}")
    return "\n".join(sections)


def _first_sentence(text: str) -> str:
    """Up to the first full stop or colon outside brackets (the bench's one-line summary)."""
    depth = 0
    for i, char in enumerate(text):
        depth += (char == "(") - (char == ")")
        if depth == 0 and char in ".:" and (i + 1 == len(text) or text[i + 1] == " "):
            return text[:i]
    return text


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--run", action="store_true", help="run the quick benches first")
    parser.add_argument("--check", action="store_true", help="exit 1 if bench/README.md is out of date; write nothing")
    args = parser.parse_args()
    if args.run:
        for script, *arguments in QUICK:
            print(f"running bench/{script} {' '.join(arguments)}".rstrip(), file=sys.stderr)
            subprocess.run([sys.executable, str(BENCH / script), *arguments], check=True)
    text = render()
    if args.check:
        if README.read_text() != text:
            sys.exit("bench/README.md is out of date: run python bench/report.py")
        return
    README.write_text(text)
    print(f"wrote {README}", file=sys.stderr)


if __name__ == "__main__":
    main()
