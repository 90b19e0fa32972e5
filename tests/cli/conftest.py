"""The command line as a user meets it: a real subprocess, where exit codes and stderr matter."""

from __future__ import annotations

import subprocess
import sys


def evp(*args, cwd=None, timeout=300) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "evp.cli", *map(str, args)], capture_output=True, text=True, cwd=cwd, timeout=timeout)
