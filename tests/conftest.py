"""Shared fixtures: where the bundled sample and the optional ../shared/data live."""

from __future__ import annotations

from pathlib import Path

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
