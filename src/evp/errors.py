"""The one exception root, :class:`EvpError`, and the exit codes of the ``evp`` command.

Every problem a user can fix (a bad command line or settings file, a bad input file, a refused or
lost link) raises a subclass of one of three categories, and the category is the exit code:

====  =========================================================================================
code  meaning
====  =========================================================================================
0     success
1     internal error: anything that is not an :class:`EvpError` is a bug (traceback shown)
2     usage: a bad command line or settings value (:class:`UsageError`; click's own errors too)
3     bad input data: a file or dataset missing, malformed or unusable (:class:`DataError`)
4     link: a station or a mobile station refused, dropped or could not be reached (:class:`LinkError`)
====  =========================================================================================

The CLI prints an :class:`EvpError` as one line (no traceback unless ``--debug``).
"""

from __future__ import annotations

import enum
from pathlib import Path


class ExitCode(enum.IntEnum):
    OK = 0
    INTERNAL = 1
    USAGE = 2
    DATA = 3
    LINK = 4


class EvpError(Exception):
    """Root of every error caused by the user's input rather than by a bug; raise a subclass."""

    exit_code: ExitCode = ExitCode.INTERNAL


class UsageError(EvpError):
    """A command-line option or a setting asks for something that does not exist or cannot be."""

    exit_code = ExitCode.USAGE


class ConfigError(UsageError):
    """A settings file is malformed or holds invalid values."""


class DataError(EvpError):
    """Input data (a file, a dataset, a frame) is missing, malformed or unusable."""

    exit_code = ExitCode.DATA


class LinkError(EvpError):
    """The link between a mobile station and a base station failed, or a peer's message is refused."""

    exit_code = ExitCode.LINK


class DataFormatError(DataError):
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


class UnknownFormatError(DataError):
    """No reader recognises a path (or the path does not exist)."""


class AmbiguousFormatError(DataError):
    """Two readers recognise a path; the user names the format (``--format``) instead of EVP guessing."""


class InitialisationError(DataError):
    """A run ended without tracking one frame: the sequence is too short, or moves too little, for
    the estimator to initialise."""


class FrameError(DataError):
    """A camera frame cannot be used (empty, or not the calibrated size); runs skip it and go on."""


class EvaluationError(DataError):
    """Two trajectories cannot be compared (no matching stamps, degenerate alignment...)."""
