"""Output paths checked before any work starts, so that a typo in ``--out`` costs a second, not
the estimation it would have ended (and lost).

A command calls :func:`writable_folder` or :func:`writable_file` on each output option it was
given, first thing; each failure is one :class:`~evp.errors.UsageError` line naming the option,
what is wrong and what to give instead. The check is the operating system's own answer (the
folder is made, the file opened for appending), not a guess from permission bits, which say
nothing to root or on a read-only mount.
"""

from __future__ import annotations

import errno
from pathlib import Path

from evp.errors import UsageError


def _reason(exc: OSError, path: Path) -> str:
    """What an OSError met while preparing ``path`` means to the user."""
    if exc.errno in (errno.ENOTDIR, errno.EEXIST):
        blocker = next((p for p in (path, *path.parents) if p.exists() and not p.is_dir()), None)
        return f"{blocker} is a file, so nothing can be made under it" if blocker is not None else "a part of the path is a file"
    if exc.errno in (errno.EACCES, errno.EPERM, errno.EROFS):
        return "cannot be written there (permission denied or a read-only disk)"
    return f"cannot be written there ({(exc.strerror or str(exc)).lower()})"


def writable_folder(path: Path | None, option: str = "--out") -> Path | None:
    """``path`` when a command can write its results into it (made when missing); else a
    UsageError. The check leaves nothing behind: folders it made for the test are removed, so a
    command that fails later on bad input has created nothing."""
    if path is None:
        return None
    if path.exists() and not path.is_dir():
        raise UsageError(f"{option} {path}: is a file, and a folder is needed here (it is made when missing); choose another name")
    made = [p for p in (path, *path.parents) if not p.exists()]
    try:
        path.mkdir(parents=True, exist_ok=True)
        probe = path / ".evp-write-check"
        probe.touch()
        probe.unlink()
    except OSError as exc:
        raise UsageError(f"{option} {path}: {_reason(exc, path)}; choose a folder you can write") from None
    finally:
        for folder in made:  # deepest first
            if folder.is_dir():
                folder.rmdir()
    return path


def writable_file(path: Path | None, option: str = "--out", example: str = "out.json") -> Path | None:
    """``path`` when a file can be written there (its folder made if missing, a file there
    replaced at the end); else a UsageError. A new file is not left behind by the check."""
    if path is None:
        return None
    if path.is_dir():
        raise UsageError(f"{option} {path}: is a folder, and a file name is needed here, e.g. {path / example}")
    existed = path.exists()
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        with open(path, "a"):
            pass
    except OSError as exc:
        raise UsageError(f"{option} {path}: {_reason(exc, path)}; choose another file name") from None
    if not existed:
        path.unlink()
    return path
