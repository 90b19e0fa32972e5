"""Tiny batch tasks for the tests: importable by local and Dask worker processes alike."""

import os
import time


def square(x: int, sleep_s: float = 0.0) -> dict:
    time.sleep(sleep_s)
    return {"x": x, "square": x * x}


def fail(message: str) -> dict:
    raise ValueError(message)


def die(code: int = 3) -> dict:
    """The worker process vanishes mid-job, as under the OOM killer."""
    os._exit(code)
