"""Shared fixtures: where the bundled sample and the optional ../shared/data live."""

from __future__ import annotations

import os
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # as the command line runs (evp/cli/__init__.py)

import pytest

PROJECT = Path(__file__).resolve().parents[1]
SAMPLE = PROJECT / "data" / "sample" / "davis_slider_depth"
SHARED_DATA = PROJECT.parent / "shared" / "data"


def shared(relative: str) -> Path:
    """A path under ../shared/data, skipping the test cleanly when that folder is absent."""
    path = SHARED_DATA / relative
    if not path.exists():
        pytest.skip(f"{path} not available (../shared/data is optional)")
    return path


@pytest.fixture
def sample_path() -> Path:
    return SAMPLE


# The modules that take longest (20 s to 2.5 min each on 2 cores, from --durations and the runs that added them), started
# first: the suite runs a module per xdist worker, and one of them left for the end ran alone for
# minutes while the other core idled.
SLOWEST_MODULES = (
    "tests/slam/test_system.py",
    "tests/station/test_limits.py",
    "tests/fusion/test_align_command.py",
    "tests/fusion/test_saved_map_start.py",
    "tests/slam/test_shared_sequences.py",
    "tests/station/test_store.py",
    "tests/slam/test_motion_classes.py",
    "tests/test_realtime_replay.py",
    "tests/station/test_end_to_end.py",
)


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """The slowest modules first (in SLOWEST_MODULES' order), the rest in collection order."""
    rank = {module: index for index, module in enumerate(SLOWEST_MODULES)}
    items.sort(key=lambda item: rank.get(item.nodeid.split("::")[0], len(rank)))
