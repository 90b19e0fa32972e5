"""Whether the station can record now: free disk space above its watermark, database writes working.

The station refuses new recording (new sessions, frames and telemetry get ``storage_full``) while
either fails, instead of taking data it cannot keep: a frame is answered only once it is
recorded, so what a mobile station saw acknowledged is never lost. The disk is measured at most
every ``CHECK_EVERY_S`` (``statvfs`` is cheap, but not per frame at 30 fps per session).
"""

from __future__ import annotations

import shutil
import time
from collections.abc import Callable
from pathlib import Path

# At the fastest a client was measured to fill a disk (21 MiB/s of frames), half a second between
# checks lets ~10 MiB in past the watermark; the default watermark (256 MB) is far larger.
CHECK_EVERY_S = 0.5


def free_bytes(path: Path) -> int:
    return shutil.disk_usage(path).free


class StorageGuard:
    """``problem()``: why the station cannot record now, or None."""

    def __init__(
        self,
        data_dir: Path,
        min_free_mb: float,
        database_problem: Callable[[], str | None],
        measure: Callable[[Path], int] = free_bytes,
        clock: Callable[[], float] = time.monotonic,
    ):
        self.data_dir = Path(data_dir)
        self.min_free_bytes = min_free_mb * 1e6
        self.database_problem = database_problem
        self.measure = measure
        self.clock = clock
        self._disk_problem: str | None = None
        self._checked_at = -float("inf")

    def problem(self) -> str | None:
        now = self.clock()
        if now - self._checked_at >= CHECK_EVERY_S:
            self._checked_at = now
            self._disk_problem = self._disk()
        return self._disk_problem or self.database_problem()

    def _disk(self) -> str | None:
        try:
            free = self.measure(self.data_dir)
        except OSError as exc:
            return f"cannot measure the free space of {self.data_dir}: {exc}"
        if free < self.min_free_bytes:
            return (
                f"{free / 1e6:.0f} MB free in {self.data_dir}, below the {self.min_free_bytes / 1e6:.0f} MB watermark (station.min_free_disk_mb): not recording"
            )
        return None
