"""bench/README.md is written by bench/report.py from the benches' docstrings and recorded results;
a hand edit, or a bench whose docstring or results changed without regenerating it, fails here."""

import subprocess
import sys
from pathlib import Path

BENCH = Path(__file__).resolve().parents[1] / "bench"


def test_bench_readme_is_what_report_writes():
    proc = subprocess.run([sys.executable, str(BENCH / "report.py"), "--check"], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stdout + proc.stderr
