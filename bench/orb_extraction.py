"""ORB extraction alone, on the same frames in one run: OpenCV's own ORB (the issue's reference),
EVP's extractor in the caller's thread, and EVP's extractor with a second thread sharing the
pyramid levels (the default). The three are timed frame by frame in turn, so machine load hits
them alike.

Usage: python bench/orb_extraction.py [--frames 100] [--only NAME ...]
"""

from __future__ import annotations

import argparse
import platform
import time
from pathlib import Path

import cv2
import numpy as np

from evp.config import Settings
from evp.io.registry import open_dataset
from evp.run_setup import camera_for
from evp.runtime.parallel import HelperThreads
from evp.vision.orb import OrbExtractor

SHARED = Path(__file__).resolve().parents[2] / "shared" / "data"
SEQUENCES = ["euroc_mh_01_easy_moving_360", "kitti_odom_06_f000-050", "davis_slider_depth"]


def _ms(extract, grey: np.ndarray) -> float:
    start = time.perf_counter()
    extract(grey)
    return (time.perf_counter() - start) * 1000


def _row(name: str, frames: int) -> str:
    dataset = open_dataset(SHARED / name)
    settings = Settings()
    camera = camera_for(dataset, settings)
    helper = HelperThreads()
    extractors = {
        "opencv": cv2.ORB_create(settings.orb.n_features).detectAndCompute,
        "one thread": OrbExtractor(settings.orb, camera).extract,
        "two threads": OrbExtractor(settings.orb, camera, helper).extract,
    }
    times: dict[str, list[float]] = {key: [] for key in extractors}
    for _, frame in zip(range(frames), dataset.frames(), strict=False):
        grey = frame.image if frame.image.ndim == 2 else cv2.cvtColor(frame.image, cv2.COLOR_BGR2GRAY)
        times["opencv"].append(_ms(lambda image: extractors["opencv"](image, None), grey))
        for key in ("one thread", "two threads"):
            times[key].append(_ms(extractors[key], grey))
    helper.close()
    median = {key: float(np.median(value)) for key, value in times.items()}
    return (
        f"| {name} | {len(times['opencv'])} | {median['opencv']:.1f} | {median['one thread']:.1f} | {median['two threads']:.1f} "
        f"| {median['two threads'] / median['opencv']:.2f} | {median['one thread'] / median['two threads']:.2f} |"
    )


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--frames", type=int, default=100)
    parser.add_argument("--only", nargs="+", choices=SEQUENCES)
    args = parser.parse_args()
    only = f" --only {' '.join(args.only)}" if args.only else ""
    print(f"command: python bench/orb_extraction.py --frames {args.frames}{only}  ({platform.node()}, {platform.machine()})\n")
    print("| sequence | frames | OpenCV ORB ms | EVP one thread ms | EVP two threads ms | two threads / OpenCV | one / two threads |")
    print("|---|---|---|---|---|---|---|")
    for name in args.only or SEQUENCES:
        if not (SHARED / name).exists():
            print(f"| {name} | missing |" + " |" * 5)
            continue
        print(_row(name, args.frames), flush=True)


if __name__ == "__main__":
    main()
