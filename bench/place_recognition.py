"""Place recognition on real images: does the keyframe database find where a frame was taken?

For each shared image sequence, every 6th frame goes into the database; the frames midway
between are the queries, as taken, turned by 90 and 180 degrees (a drone coming back on another
heading) and seen from further away (0.75x, another height). A query is recognised when its
best-scoring database frame is one of its two neighbours. Methods: small thumbnails (what the
relocaliser used before the vocabulary), the shipped vocabulary (trained on EVP's renders only)
and a vocabulary trained the same way on the *other* shared sequences (leave one out: what
training on real images would give).

Usage: python bench/place_recognition.py [--only SEQ ...] [--step 6]

Prints per sequence and view the share of queries recognised by each method. Needs
../shared/data; it trains one vocabulary per sequence.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import cv2
import numpy as np
from results import Results

from evp.config import OrbSettings
from evp.io.registry import open_dataset
from evp.io.vocabulary_files import default_vocabulary_path, load_vocabulary
from evp.types import CameraModel
from evp.vision.images import grey_image
from evp.vision.orb import OrbExtractor
from evp.vision.vocabulary import bow_score, train_vocabulary

SHARED = Path(__file__).resolve().parents[1].parent / "shared" / "data"
SEQUENCES = ["euroc_mh_01_easy_moving_360", "kitti_odom_06_f000-050", "davis_slider_depth", "aerial_nadir_odm_toledo_fc350"]
VIEWS = {
    "as taken": lambda g: g,
    "turned 90 deg": lambda g: cv2.rotate(g, cv2.ROTATE_90_CLOCKWISE),
    "turned 180 deg": lambda g: cv2.rotate(g, cv2.ROTATE_180),
    "from 0.75x": lambda g: cv2.copyMakeBorder(
        cv2.resize(g, None, fx=0.75, fy=0.75, interpolation=cv2.INTER_AREA), *_pads(g.shape, 0.75), cv2.BORDER_CONSTANT, value=int(np.median(g))
    ),
}


def _pads(shape: tuple[int, int], factor: float) -> tuple[int, int, int, int]:
    h, w = shape
    dh, dw = h - round(h * factor), w - round(w * factor)
    return dh // 2, dh - dh // 2, dw // 2, dw - dw // 2


def _thumbnail(grey: np.ndarray) -> np.ndarray:
    small = cv2.GaussianBlur(cv2.resize(grey, (40, 30), interpolation=cv2.INTER_AREA).astype(np.float32), (0, 0), 1.5).ravel()
    small -= small.mean()
    return small / max(float(np.linalg.norm(small)), 1e-6)


def _frames(name: str) -> tuple[list[np.ndarray], CameraModel]:
    dataset = open_dataset(SHARED / name)
    return [grey_image(frame, dataset.camera) for frame in dataset.frames()], dataset.camera


def _descriptors(extractor: OrbExtractor, grey: np.ndarray) -> np.ndarray:
    return extractor.extract(grey).descriptors


_BY_SHAPE: dict[tuple[int, int], OrbExtractor] = {}


def _any_image_descriptors(grey: np.ndarray) -> np.ndarray:
    """Descriptors of a turned or shrunk view (a pinhole of its own size: only descriptors count)."""
    h, w = grey.shape
    if (h, w) not in _BY_SHAPE:
        _BY_SHAPE[(h, w)] = OrbExtractor(OrbSettings(), CameraModel(width=w, height=h, fx=w, fy=w, cx=w / 2, cy=h / 2))
    return _descriptors(_BY_SHAPE[(h, w)], grey)


def _recall(database_scores: list[np.ndarray], neighbours: list[tuple[int, int]]) -> float:
    hits = [int(np.argmax(scores)) in pair for scores, pair in zip(database_scores, neighbours)]
    return float(np.mean(hits)) if hits else float("nan")


COLUMNS = [
    ("sequence", "{sequence}"),
    ("database / queries", "{database} / {queries}"),
    ("view", "{view}"),
    ("thumbnail", "{thumbnail:.0%}"),
    ("vocabulary from renders (shipped)", "{shipped:.0%}"),
    ("vocabulary from the other real sequences", "{leave_one_out:.0%}"),
]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--only", nargs="+", choices=SEQUENCES)
    parser.add_argument("--step", type=int, default=6, help="database frames this far apart (queries midway)")
    args = parser.parse_args()
    if not SHARED.exists():
        sys.exit(f"needs the shared sequences in {SHARED}")
    names = args.only or SEQUENCES
    images, extractors = {}, {}
    for name in SEQUENCES:
        frames, camera = _frames(name)
        images[name] = frames
        extractors[name] = OrbExtractor(OrbSettings(), camera)
        print(f"read {name}: {len(frames)} frames", file=sys.stderr)
    shipped = load_vocabulary(default_vocabulary_path())
    command = f"python bench/place_recognition.py {' '.join(sys.argv[1:])}".rstrip()
    print(f"command: {command}")
    print()
    table = Results("place_recognition", command).table(
        "recall", COLUMNS, key=["sequence", "step", "view"], caption="Share of queries whose best database frame is a neighbour"
    )
    print(table.header())
    for name in names:
        frames, extractor = images[name], extractors[name]
        others = [
            d for other in SEQUENCES if other != name for d in (_descriptors(extractors[other], g) for g in images[other][:: max(1, len(images[other]) // 80)])
        ]
        leave_one_out = train_vocabulary(others, 10, 4, seed=0)
        database = list(range(0, len(frames), args.step))
        queries = [q for q in range(args.step // 2, len(frames), args.step) if q + args.step // 2 < len(frames)]
        neighbours = [(database.index(q - args.step // 2), database.index(q + args.step // 2)) for q in queries]
        db_desc = [_descriptors(extractor, frames[i]) for i in database]
        db_thumbs = np.array([_thumbnail(frames[i]) for i in database])
        db_bows = {key: [voc.transform(d) for d in db_desc] for key, voc in (("shipped", shipped), ("real", leave_one_out))}
        for view, transform in VIEWS.items():
            seen = [transform(frames[q]) for q in queries]
            thumb_scores = [db_thumbs @ _thumbnail(cv2.resize(g, (frames[0].shape[1], frames[0].shape[0]))) for g in seen]
            recalls = [_recall(thumb_scores, neighbours)]
            query_desc = [_any_image_descriptors(g) for g in seen]
            for key, voc in (("shipped", shipped), ("real", leave_one_out)):
                scores = [np.array([bow_score(voc.transform(d), b) for b in db_bows[key]]) for d in query_desc]
                recalls.append(_recall(scores, neighbours))
            record = {"sequence": name, "step": args.step, "database": len(database), "queries": len(queries), "view": view}
            print(table.add({**record, "thumbnail": recalls[0], "shipped": recalls[1], "leave_one_out": recalls[2]}), flush=True)


if __name__ == "__main__":
    main()
