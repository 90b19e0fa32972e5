"""Small numeric text tables (CSV or whitespace separated) with line-exact error messages."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from evp.errors import DataFormatError, DatasetError


def read_text_file(path: Path, error: type[DataFormatError] = DatasetError) -> str:
    """A text file's contents; a missing, unreadable or binary file (undecodable bytes, NUL) is
    one specific ``error`` naming the file."""
    if not path.is_file():
        raise error(path, "file not found")
    try:
        text = path.read_text()
    except UnicodeDecodeError as exc:
        raise error(path, f"not a text file (byte 0x{exc.object[exc.start]:02x} at offset {exc.start} is not UTF-8)") from None
    except OSError as exc:
        raise error(path, f"cannot be read: {exc.strerror or exc}") from None
    if "\x00" in text:
        raise error(path, f"not a text file (a NUL byte at offset {text.index(chr(0))})")
    return text


def read_table(
    path: Path,
    columns: int | None = None,
    min_columns: int = 1,
    delimiter: str | None = None,
    header: bool | None = None,
    allow_empty: bool = False,
) -> tuple[np.ndarray, list[int], list[str]]:
    """Numeric rows of a text table.

    Lines starting with ``#`` are comments; a first line that is not numeric is a header when
    ``header`` is None. Returns (values, 1-based line numbers, header fields). A table with no
    rows is an error unless ``allow_empty`` (a sensor's log that recorded nothing: (0, columns)).
    """
    text = read_text_file(path)
    rows: list[list[float]] = []
    numbers: list[int] = []
    names: list[str] = []
    for number, raw in enumerate(text.splitlines(), start=1):
        line = raw.strip()
        if not line or line.startswith("#"):
            continue
        sep = delimiter if delimiter is not None else ("," if "," in line else None)
        fields = [f.strip() for f in line.split(sep)]
        try:
            values = [float(f) for f in fields]
        except ValueError as exc:
            if not rows and not names and header is not False:
                names = fields
                continue
            raise DatasetError(path, f"not a number: {exc}", line=number) from exc
        if columns is not None and len(values) != columns:
            raise DatasetError(path, f"expected {columns} values, found {len(values)}", line=number)
        if len(values) < min_columns:
            raise DatasetError(path, f"expected at least {min_columns} values, found {len(values)}", line=number)
        if rows and len(values) != len(rows[0]):
            raise DatasetError(path, f"expected {len(rows[0])} values like the first row, found {len(values)}", line=number)
        rows.append(values)
        numbers.append(number)
    if not rows:
        if allow_empty:
            return np.zeros((0, columns or 0)), [], names
        raise DatasetError(path, "no data rows")
    return np.array(rows, dtype=float), numbers, names


def read_named_lines(path: Path) -> tuple[np.ndarray, list[str], list[int]]:
    """Lines of ``timestamp name`` pairs (TUM rgb.txt, RPG images.txt, EuRoC data.csv)."""
    text = read_text_file(path)
    stamps: list[float] = []
    names: list[str] = []
    numbers: list[int] = []
    for number, raw in enumerate(text.splitlines(), start=1):
        line = raw.strip()
        if not line or line.startswith("#"):
            continue
        fields = [f.strip() for f in (line.split(",") if "," in line else line.split())]
        if len(fields) < 2:
            raise DatasetError(path, "expected 'timestamp filename'", line=number)
        try:
            stamps.append(float(fields[0]))
        except ValueError as exc:
            if not stamps:
                continue  # header line
            raise DatasetError(path, f"bad timestamp: {exc}", line=number) from exc
        names.append(fields[1])
        numbers.append(number)
    if not stamps:
        raise DatasetError(path, "no entries")
    return np.array(stamps), names, numbers
