"""Where the experiments find the real recordings they run on: ``$EVP_SHARED_DATA/NAME``
(default ``../shared/data/NAME`` from the working directory, the checkout's sibling)."""

from __future__ import annotations

import os
from pathlib import Path


def shared_data_folder(name: str) -> Path:
    return Path(os.environ.get("EVP_SHARED_DATA", Path.cwd().parent / "shared" / "data")) / name
