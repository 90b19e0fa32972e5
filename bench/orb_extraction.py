"""ORB extraction alone: OpenCV's own ORB (the reference the SLAM issue's speed aim is set
against), EVP's extractor in the caller's thread, and EVP's extractor with a second thread sharing
the pyramid levels (the default). The three are timed frame by frame in turn on the same frames,
so machine load hits them alike.

Usage: python bench/orb_extraction.py [--frames 100] [--only SEQ ...]

Prints per sequence the median ms of each and two ratios: two threads against OpenCV, and one
thread against two. Needs ../shared/data.
"""

from __future__ import annotations

import argparse
import platform
import time
from pathlib import Path

import cv2
import numpy as np
from results import Results

from evp.config import Settings
from evp.io.registry import open_dataset
from evp.run_setup import camera_for
from evp.runtime.parallel import HelperThreads
from evp.vision.images import to_grey
from evp.vision.orb import OrbExtractor

SHARED = Path(__file__).resolve().parents[2] / "shared" / "data"
SEQUENCES = ["euroc_mh_01_easy_moving_360", "kitti_odom_06_f000-050", "davis_slider_depth"]


def _ms(extract, grey: np.ndarray) -> float:
    start = time.perf_counter()
    extract(grey)
    return (time.perf_counter() - start) * 1000


COLUMNS = [
    ("sequence", "{sequence}"),
    ("frames", "{frames}"),
    ("OpenCV ORB ms", "{opencv_ms:.1f}"),
    ("EVP one thread ms", "{one_thread_ms:.1f}"),
    ("EVP two threads ms", "{two_threads_ms:.1f}"),
    ("two threads / OpenCV", "{two_threads_to_opencv:.2f}"),
    ("one / two threads", "{one_to_two_threads:.2f}"),
]


def _record(name: str, frames: int) -> dict:
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
        grey = to_grey(frame.image)
        times["opencv"].append(_ms(lambda image: extractors["opencv"](image, None), grey))
        for key in ("one thread", "two threads"):
            times[key].append(_ms(extractors[key], grey))
    helper.close()
    median = {key: float(np.median(value)) for key, value in times.items()}
    return {
        "sequence": name,
        "frames": len(times["opencv"]),
        "opencv_ms": median["opencv"],
        "one_thread_ms": median["one thread"],
        "two_threads_ms": median["two threads"],
        "two_threads_to_opencv": median["two threads"] / median["opencv"],
        "one_to_two_threads": median["one thread"] / median["two threads"],
    }


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--frames", type=int, default=100)
    parser.add_argument("--only", nargs="+", choices=SEQUENCES)
    args = parser.parse_args()
    only = f" --only {' '.join(args.only)}" if args.only else ""
    command = f"python bench/orb_extraction.py --frames {args.frames}{only}"
    print(f"command: {command}  ({platform.node()}, {platform.machine()})\n")
    table = Results("orb_extraction", command).table("extraction", COLUMNS, key=["sequence"], caption="Median ms per frame, timed in turn on the same frames")
    print(table.header())
    for name in args.only or SEQUENCES:
        if not (SHARED / name).exists():
            print(f"| {name} | missing |" + " |" * 5)
            continue
        print(table.add(_record(name, args.frames)), flush=True)


if __name__ == "__main__":
    main()
