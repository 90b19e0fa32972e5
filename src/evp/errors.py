"""Exceptions EVP raises for problems a user can fix (bad files, bad settings).

The CLI prints these as one line (no traceback unless ``--debug``); anything else is a bug.
"""

from __future__ import annotations

from pathlib import Path


class EvpError(Exception):
    """Base class of every error caused by the user's input rather than by a bug."""


class DataFormatError(EvpError):
    """A file does not follow its format; names the file and, when known, the line or record."""

    def __init__(self, path: str | Path, message: str, line: int | None = None, record: str | None = None):
        self.path = Path(path)
        self.line = line
        self.record = record
        where = str(self.path)
        if line is not None:
            where += f", line {line}"
        if record is not None:
            where += f", record {record}"
        super().__init__(f"{where}: {message}")


class TrajectoryFormatError(DataFormatError):
    """A trajectory file (TUM, KITTI, EuRoC CSV) is malformed."""


class DatasetError(DataFormatError):
    """A dataset folder or file is malformed or incomplete."""


class CalibrationError(DataFormatError):
    """A calibration file is missing, malformed or inconsistent."""


class UnknownFormatError(EvpError):
    """No reader recognises a path."""


class ConfigError(EvpError):
    """A settings file is malformed or holds invalid values."""


class EvaluationError(EvpError):
    """Two trajectories cannot be compared (no matching stamps, degenerate alignment...)."""
