"""Training a bag-of-words vocabulary (``evp vocabulary build``): ORB descriptors of EVP's
rendered training scenes, or of the user's own recordings, through the tracker's extractor."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from evp import __version__
from evp.config import OrbSettings
from evp.errors import DatasetError
from evp.vision.orb import OrbExtractor
from evp.vision.vocabulary import Vocabulary, train_vocabulary

if TYPE_CHECKING:
    from evp.sim.vocabulary_images import TrainingScene


def rendered_descriptors(
    frames_per_scene: int, orb: OrbSettings, on_image: Callable[[], None] | None = None, scenes: tuple[TrainingScene, ...] | None = None
) -> tuple[list[np.ndarray], list[str]]:
    """Descriptors of each rendered training image, and the scenes they came from (all training
    scenes unless ``scenes`` names some)."""
    from evp.sim.vocabulary_images import TRAINING_SCENES, training_images

    scenes = TRAINING_SCENES if scenes is None else scenes
    sets, extractors = [], {}
    for label, camera, grey in training_images(frames_per_scene, scenes):
        extractor = extractors.setdefault(label, OrbExtractor(orb, camera))
        sets.append(extractor.extract(grey).descriptors)
        if on_image is not None:
            on_image()
    return sets, [scene.label for scene in scenes]


def dataset_descriptors(paths: list[Path], every: int, orb: OrbSettings, on_image: Callable[[], None] | None = None) -> tuple[list[np.ndarray], list[str]]:
    """Descriptors of every ``every``-th frame of each dataset (any format ``evp info`` reads)."""
    from evp.io.registry import open_dataset
    from evp.vision.images import grey_image

    sets, names = [], []
    for path in paths:
        dataset = open_dataset(path)
        if dataset.num_frames == 0:
            raise DatasetError(path, f"no camera frames to train a vocabulary on ({dataset.format})")
        extractor = OrbExtractor(orb, dataset.camera)
        for index, frame in enumerate(dataset.frames()):
            if index % every == 0:
                sets.append(extractor.extract(grey_image(frame, dataset.camera)).descriptors)
                if on_image is not None:
                    on_image()
        names.append(f"{dataset.name} ({dataset.format}, every {every} frames)")
    return sets, names


def build_vocabulary(
    sets: list[np.ndarray], sources: list[str], branching: int, depth: int, orb: OrbSettings, progress: Callable[[int, int], None] | None = None
) -> Vocabulary:
    notes = {
        "trained_on": sources,
        "images": len(sets),
        "descriptors": int(sum(len(d) for d in sets)),
        "orb": orb.model_dump(),
        "built_by": f"evp {__version__} vocabulary build",
    }
    return train_vocabulary(sets, branching, depth, notes=notes, progress=progress)
