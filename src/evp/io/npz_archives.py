"""EVP's ``.npz`` files (maps, radio maps): arrays plus a JSON ``meta`` naming the format."""

from __future__ import annotations

import json
import zipfile
from pathlib import Path

import numpy as np

from evp.errors import DataFormatError


def read_archive(path: Path, format_name: str, what: str) -> tuple[dict[str, np.ndarray], dict]:
    """Every array of the archive (each read once: indexing an archive decompresses the whole
    array again) and its meta; a file that is not one, or of another format, is a clear error
    naming ``what`` it should have been."""
    try:
        with np.load(Path(path), allow_pickle=False) as archive:
            data = {name: archive[name] for name in archive.files}
        meta = json.loads(str(data["meta"]))
    except (OSError, EOFError, ValueError, KeyError, zipfile.BadZipFile) as exc:
        raise DataFormatError(path, f"not {what} ({exc})") from exc
    if meta.get("format") != format_name:
        raise DataFormatError(path, f"not {what}")
    return data, meta
