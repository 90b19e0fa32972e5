"""Is the shipped vocabulary (``src/evp/vision/orb_vocabulary.npz``) the one ``evp vocabulary
build`` makes? Rebuilds it from EVP's renders with the command's defaults (40 images per training
scene, 10 branches x 4 levels, the default ORB settings), compares it word for word and prints how
long each step took. Run it after changing the extractor, the renderer or the training scenes; a
difference means the file must be rebuilt with ``evp vocabulary build --out
src/evp/vision/orb_vocabulary.npz``. The tests check the same code path on one render per scene.

    python bench/shipped_vocabulary.py [--frames-per-scene 40]
"""

from __future__ import annotations

import argparse
import sys
import time

import numpy as np

from evp.config import OrbSettings
from evp.io.vocabulary_files import default_vocabulary_path, load_vocabulary
from evp.vocabulary_training import build_vocabulary, rendered_descriptors


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames-per-scene", type=int, default=40)
    args = parser.parse_args()
    orb = OrbSettings()
    start = time.perf_counter()
    sets, sources = rendered_descriptors(args.frames_per_scene, orb)
    rendered = time.perf_counter()
    built = build_vocabulary(sets, sources, 10, 4, orb)
    trained = time.perf_counter()
    shipped = load_vocabulary(default_vocabulary_path())
    checks = {
        "tree (centres, children)": np.array_equal(built.centres, shipped.centres) and np.array_equal(built.children, shipped.children),
        "word weights (idf)": bool(np.allclose(built.idf, shipped.idf)),
        "sources and ORB settings in its notes": shipped.notes["trained_on"] == sources and shipped.notes["orb"] == orb.model_dump(),
    }
    print(f"command: python bench/shipped_vocabulary.py --frames-per-scene {args.frames_per_scene}\n")
    print("| step | seconds |\n|---|---|")
    print(f"| render and extract ({len(sets)} images, {sum(len(d) for d in sets)} descriptors) | {rendered - start:.1f} |")
    print(f"| train ({built.n_words} words) | {trained - rendered:.1f} |\n")
    print("| shipped file matches the rebuild | |\n|---|---|")
    for name, same in checks.items():
        print(f"| {name} | {'yes' if same else 'NO'} |")
    return 0 if all(checks.values()) else 1


if __name__ == "__main__":
    sys.exit(main())
