"""Seed 001's Figure 4 with today's numbers: detection + description, matching and match quality
of OpenCV's ORB, SIFT, AKAZE, BRISK and SURF on real frame pairs at QVGA (320x240), 640x380 and
VGA (640x480). ``evp bench features`` and ``bench/feature_detectors.py`` run it.

Per detector and size: keypoints per image, detection + description ms per image, matching ms per
pair (brute force, Hamming for the binary descriptors and L2 for SIFT and SURF, Lowe's ratio test
0.8), matches kept, and the share of them that a RANSAC fundamental matrix (1 px) accepts (match
quality), medians over the pairs. OpenCV should run with one thread (``cv2.setNumThreads(1)``,
the caller's choice). A detector the installed OpenCV lacks is reported as absent (OpenCV 5
keeps AKAZE, BRISK and the patented SURF in opencv_contrib only).
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator
from functools import partial
from pathlib import Path

import cv2
import numpy as np

SIZES = {"QVGA 320x240": (320, 240), "640x380": (640, 380), "VGA 640x480": (640, 480)}
RATIO = 0.8  # Lowe's ratio test
DETECTORS = {  # name: (constructor name in cv2, arguments, descriptor norm)
    "ORB": ("ORB_create", (1000,), cv2.NORM_HAMMING),
    "SIFT": ("SIFT_create", (1000,), cv2.NORM_L2),
    "AKAZE": ("AKAZE_create", (), cv2.NORM_HAMMING),
    "BRISK": ("BRISK_create", (), cv2.NORM_HAMMING),
    "SURF": ("SURF_create", (), cv2.NORM_L2),
}
# the real frames of ../shared/data the bench uses: EuRoC MH01's cam0 (752x480) and KITTI 06 (1241x376)
FRAME_FOLDERS = (("euroc_mh_01_easy_moving_360", "mav0/cam0/data"), ("kitti_odom_06_f000-050", ""))


def frame_pairs(shared: Path, count: int) -> list[tuple[np.ndarray, np.ndarray]]:
    """``count`` consecutive grey frame pairs, half from each of FRAME_FOLDERS under ``shared``."""
    pairs = []
    for folder, inside in FRAME_FOLDERS:
        files = sorted((shared / folder / inside).rglob("*.png"))
        for a, b in zip(files[: count // 2], files[1 : count // 2 + 1]):
            pairs.append((cv2.imread(str(a), cv2.IMREAD_GRAYSCALE), cv2.imread(str(b), cv2.IMREAD_GRAYSCALE)))
    return pairs


def absent_detectors() -> list[str]:
    return [name for name, (constructor, _, _) in DETECTORS.items() if not hasattr(cv2, constructor)]


def measure(make: Callable, norm: int, pairs: list, size: tuple[int, int]) -> dict:
    """One detector at one size over ``pairs``: the medians described in the module docstring."""
    detector, matcher = make(), cv2.BFMatcher(norm)
    keypoints, detect_ms, match_ms, kept, inliers = [], [], [], [], []
    for first, second in pairs:
        described = []
        for image in (first, second):
            image = cv2.resize(image, size, interpolation=cv2.INTER_AREA)
            start = time.perf_counter()
            points, descriptors = detector.detectAndCompute(image, None)
            detect_ms.append(1000 * (time.perf_counter() - start))
            keypoints.append(len(points))
            described.append((points, descriptors))
        (p1, d1), (p2, d2) = described
        if d1 is None or d2 is None or len(p1) < 8 or len(p2) < 8:
            continue
        start = time.perf_counter()
        good = [m for m, n in (pair for pair in matcher.knnMatch(d1, d2, k=2) if len(pair) == 2) if m.distance < RATIO * n.distance]
        match_ms.append(1000 * (time.perf_counter() - start))
        kept.append(len(good))
        if len(good) >= 8:
            a = np.float32([p1[m.queryIdx].pt for m in good])
            b = np.float32([p2[m.trainIdx].pt for m in good])
            _, mask = cv2.findFundamentalMat(a, b, cv2.FM_RANSAC, 1.0, 0.999)
            inliers.append(float(mask.mean()) if mask is not None else 0.0)
    return {
        "keypoints": float(np.median(keypoints)),
        "detect_ms": float(np.median(detect_ms)),
        "match_ms": float(np.median(match_ms)) if match_ms else None,
        "matches": float(np.median(kept)) if kept else None,
        "inlier_percent": 100 * float(np.median(inliers)) if inliers else None,
    }


def measure_all(pairs: list) -> Iterator[dict]:
    """A record per available detector and size, as each is measured."""
    for name, (constructor, arguments, norm) in DETECTORS.items():
        if name in absent_detectors():
            continue
        for size_name, size in SIZES.items():
            yield {"detector": name, "size": size_name, **measure(partial(getattr(cv2, constructor), *arguments), norm, pairs, size)}


def absent_note() -> str | None:
    absent = absent_detectors()
    if not absent:
        return None
    return f"Not in the installed OpenCV {cv2.__version__}: {', '.join(absent)} (OpenCV 5 moved AKAZE and BRISK to opencv_contrib; SURF is patented and only there)."
