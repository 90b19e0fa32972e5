"""Vocabulary files (one ``.npz``: the tree's arrays and a JSON header), and the vocabulary
shipped with EVP (10 x 4 levels, trained on EVP's renders by ``evp vocabulary build``)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from evp.errors import DataFormatError
from evp.vision.vocabulary import Vocabulary

FORMAT = "evp-orb-vocabulary"


def default_vocabulary_path() -> Path:
    """The vocabulary shipped with EVP."""
    return Path(__file__).with_name("orb_vocabulary.npz")


def save_vocabulary(vocabulary: Vocabulary, path: Path) -> None:
    meta = {"format": FORMAT, "version": 1, "branching": vocabulary.branching, "depth": vocabulary.depth, "notes": vocabulary.notes}
    np.savez_compressed(
        Path(path),
        meta=np.array(json.dumps(meta)),
        centres=vocabulary.centres,
        children=vocabulary.children,
        word_of_node=vocabulary.word_of_node,
        idf=vocabulary.idf,
    )


def load_vocabulary(path: Path) -> Vocabulary:
    """A vocabulary file; a missing, foreign or corrupt file is a clear error naming it."""
    try:
        with np.load(Path(path), allow_pickle=False) as archive:
            data = {name: archive[name] for name in archive.files}
        meta = json.loads(str(data["meta"]))
    except FileNotFoundError as exc:
        raise DataFormatError(path, "no such vocabulary file") from exc
    except Exception as exc:  # a zip, pickle or JSON error: the file is not what it should be
        raise DataFormatError(path, f"not an EVP vocabulary file ({exc})") from exc
    if meta.get("format") != FORMAT:
        raise DataFormatError(path, "not an EVP vocabulary file")
    vocabulary = Vocabulary(meta["branching"], meta["depth"], data["centres"], data["children"], data["word_of_node"], data["idf"], meta.get("notes", {}))
    problems = vocabulary.problems()
    if problems:
        raise DataFormatError(path, f"corrupt vocabulary ({'; '.join(problems)})")
    return vocabulary


def load_configured_vocabulary(path: str | Path | None) -> Vocabulary:
    """The vocabulary of the ``slam.vocabulary`` setting, or the shipped one when it is not set."""
    return load_vocabulary(Path(path) if path else default_vocabulary_path())
