"""Seed 001's Figure 4 with today's numbers (evp.eval.feature_timing; ``evp bench features`` runs
the same measurement): detection + description, matching and match quality of ORB, SIFT, AKAZE,
BRISK and SURF on real frames at QVGA (320x240), VGA (640x480) and 640x380, on one core. A
detector the installed OpenCV lacks is named as absent in the run's note.

Usage: python bench/feature_detectors.py [--pairs 20]

Frames: consecutive pairs of EuRoC MH01 (cam0, 752x480) and KITTI 06 (1241x376) from
../shared/data, each resized to the three sizes (the aspect ratio changes with it). A row per
detector and size: keypoints per image, detection + description ms per image, matching ms per
pair (brute force, Hamming for the binary descriptors and L2 for SIFT, Lowe's ratio test 0.8),
matches kept, and the share of them that a RANSAC fundamental matrix (1 px) accepts (match
quality), medians over the pairs. OpenCV runs with one thread (``cv2.setNumThreads(1)``).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import cv2
from results import Results

from evp.eval.feature_timing import absent_note, frame_pairs, measure_all

SHARED = Path(__file__).resolve().parents[2] / "shared" / "data"
COLUMNS = [
    ("detector", "{detector}"),
    ("size", "{size}"),
    ("keypoints", "{keypoints:.0f}"),
    ("detect+describe ms", "{detect_ms:.1f}"),
    ("match ms", "{match_ms:.1f}"),
    ("matches kept", "{matches:.0f}"),
    ("RANSAC inliers", "{inlier_percent:.0f} %"),
]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--pairs", type=int, default=20)
    args = parser.parse_args()
    cv2.setNumThreads(1)
    pairs = frame_pairs(SHARED, args.pairs)
    results = Results("feature_detectors", "python bench/feature_detectors.py " + " ".join(sys.argv[1:]))
    table = results.table("detectors", COLUMNS, ["detector", "size"], f"{len(pairs)} consecutive real frame pairs, one thread")
    print(table.header())
    for record in measure_all(pairs):
        print(table.add(record), flush=True)
    note = absent_note()
    if note:
        print(note)
        results.note(note)


if __name__ == "__main__":
    main()
