"""The explicit registry of dataset readers and path auto-detection.

A reader is a small object with a ``name``, a one-line ``description``, what its detection
``looks_for``, ``detect(path) -> bool`` and ``read(path) -> Dataset``. Readers are listed in
:mod:`evp.io.readers`; adding a format is adding one module and one line there.

Detection never guesses between formats: a path that two readers claim is refused with both names
and the ``--format`` option that settles it, and a path that none claims is refused with what
each reader looked for.
"""

from __future__ import annotations

from pathlib import Path
from typing import Protocol

from evp.errors import AmbiguousFormatError, UnknownFormatError, UsageError
from evp.io.dataset import Dataset


class DatasetReader(Protocol):
    name: str
    description: str
    looks_for: str

    def detect(self, path: Path) -> bool: ...

    def read(self, path: Path) -> Dataset: ...


def readers() -> list[DatasetReader]:
    """Every reader, the fallbacks last."""
    from evp.io.readers import FALLBACK_READERS, READERS

    return [*READERS, *FALLBACK_READERS]


def reader_by_name(name: str) -> DatasetReader:
    """The reader ``--format NAME`` names; a misspelt name is a usage error naming the nearest."""
    from difflib import get_close_matches

    names = [reader.name for reader in readers()]
    for reader in readers():
        if reader.name == name:
            return reader
    close = get_close_matches(name, names, n=1, cutoff=0.6)
    raise UsageError(f"--format {name!r}: no such dataset format; " + (f"did you mean {close[0]}? " if close else "") + f"known: {', '.join(names)}")


def detect_reader(path: str | Path) -> DatasetReader:
    """The one reader that recognises ``path``; :class:`AmbiguousFormatError` when two do."""
    from evp.io.readers import FALLBACK_READERS, READERS

    path = Path(path)
    if not path.exists():
        raise UnknownFormatError(f"{path}: no such file or folder")
    for candidates in (READERS, FALLBACK_READERS):
        if candidates is FALLBACK_READERS and path.is_dir():
            refuse_a_part_of_a_dataset(path)  # mav0/cam0's data.csv is no trajectory to show
        matches = [reader for reader in candidates if reader.detect(path)]
        if len(matches) > 1:
            found = " and ".join(f"{r.name} ({r.looks_for})" for r in matches)
            choose = " or ".join(f"--format {r.name}" for r in matches)
            raise AmbiguousFormatError(f"{path}: matches more than one dataset format: {found}; name the one to read with {choose}")
        if matches:
            return matches[0]
    raise UnknownFormatError(f"{path}: {what_is_missing(path)}")


# how far up a folder given by mistake can be from its dataset's root: EuRoC's mav0/cam0/data is 3
MAX_DATASET_DEPTH = 3


def refuse_a_part_of_a_dataset(folder: Path) -> None:
    """A folder inside a dataset that a reader recognises (EuRoC's mav0/cam0, KITTI's image_0,
    the sample's images/) is refused with the dataset's root, which is what to give."""
    from evp.io.readers import READERS

    for parent in list(folder.absolute().parents)[:MAX_DATASET_DEPTH]:
        for reader in READERS:
            if reader.detect(parent):
                raise UnknownFormatError(f"{folder}: a part of the {reader.name} dataset {parent}; give that folder")


def what_is_missing(path: Path) -> str:
    """Why no reader took ``path``, said for the three near misses a new user makes (an empty
    folder, a bare folder of images, a folder of other files), else what each reader looked for."""
    from evp.io.readers.image_folder import IMAGE_SUFFIXES
    from evp.io.readers.video import VIDEO_SUFFIXES

    looked = "; ".join(f"{r.name}: {r.looks_for}" for r in readers())
    if not path.is_dir():
        return f"not a dataset file EVP reads ({path.suffix or 'no suffix'}); evp formats lists the formats (looked for {looked})"
    files = [p for p in path.iterdir() if not p.name.startswith(".")]
    if not files:
        return "the folder is empty; give a dataset folder, a video or a bag (evp formats lists what EVP reads)"
    images = [p for p in (path / "images" if (path / "images").is_dir() else path).iterdir() if p.suffix.lower() in IMAGE_SUFFIXES]
    if images:
        return (
            f"a folder of {len(images)} images needs their times: times.txt (one time in seconds per line, for the images in name order) "
            "or images.txt ('time filename' lines) beside them, and a calibration: calib.txt ('fx fy cx cy [k1 k2 p1 p2 [k3]]'), "
            "camera.yaml, or --camera FILE|PROFILE (evp camera list)"
        )
    videos = [p for p in files if p.suffix.lower() in VIDEO_SUFFIXES]
    if videos:
        return f"the folder holds a video: give the video file itself, e.g. {videos[0]}"
    if not any(p.is_dir() for p in files):
        suffixes = sorted({p.suffix.lower() or "(none)" for p in files})
        return f"no images, video or recording here (its {len(files)} files end {', '.join(suffixes[:6])}); evp formats lists what EVP reads"
    return f"not a dataset EVP recognises (looked for {looked})"


def open_dataset(path: str | Path, fmt: str | None = None) -> Dataset:
    """Read a dataset, detecting its format from the path unless ``fmt`` names a reader."""
    reader = reader_by_name(fmt) if fmt else detect_reader(path)
    return reader.read(Path(path))
