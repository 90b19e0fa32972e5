"""The explicit registry of dataset readers and path auto-detection.

A reader is a small object with a ``name``, a one-line ``description``, ``detect(path) -> bool``
and ``read(path) -> Dataset``. Readers are listed in :mod:`evp.io.readers` in detection order
(most specific first); adding a format is adding one module and one line there.
"""

from __future__ import annotations

from pathlib import Path
from typing import Protocol

from evp.errors import UnknownFormatError
from evp.io.dataset import Dataset


class DatasetReader(Protocol):
    name: str
    description: str

    def detect(self, path: Path) -> bool: ...

    def read(self, path: Path) -> Dataset: ...


def readers() -> list[DatasetReader]:
    from evp.io.readers import READERS

    return list(READERS)


def reader_by_name(name: str) -> DatasetReader:
    for reader in readers():
        if reader.name == name:
            return reader
    raise UnknownFormatError(f"unknown dataset format {name!r}; known: {', '.join(r.name for r in readers())}")


def detect_reader(path: str | Path) -> DatasetReader:
    path = Path(path)
    if not path.exists():
        raise UnknownFormatError(f"{path}: no such file or folder")
    for reader in readers():
        if reader.detect(path):
            return reader
    raise UnknownFormatError(f"{path}: not a dataset EVP recognises (formats: {', '.join(r.name for r in readers())})")


def open_dataset(path: str | Path, fmt: str | None = None) -> Dataset:
    """Read a dataset, detecting its format from the path unless ``fmt`` names a reader."""
    reader = reader_by_name(fmt) if fmt else detect_reader(path)
    return reader.read(Path(path))
