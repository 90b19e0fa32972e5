"""``evp bench features``' measurement (seed 001's Figure 4) on a synthetic pair, and the command
on a folder without the frames it needs."""

from __future__ import annotations

from functools import partial

import cv2
import numpy as np

from evp.eval.feature_timing import DETECTORS, measure
from tests.cli.conftest import evp


def test_orb_on_a_shifted_texture_matches_with_epipolar_inliers():
    rng = np.random.default_rng(0)
    texture = cv2.GaussianBlur((rng.random((300, 420)) * 255).astype(np.uint8), (5, 5), 1.5)
    pair = (texture[:240, :320].copy(), texture[6:246, 4:324].copy())  # the camera moved 4 px, 6 px
    constructor, arguments, norm = DETECTORS["ORB"]
    record = measure(partial(getattr(cv2, constructor), *arguments), norm, [pair], (320, 240))
    assert record["keypoints"] > 100 and record["matches"] > 50 and record["inlier_percent"] > 80
    assert record["detect_ms"] > 0 and record["match_ms"] > 0


def test_the_command_names_the_frames_it_did_not_find(tmp_path):
    result = evp("bench", "features", "--data", tmp_path)
    assert result.returncode != 0 and "euroc_mh_01" in result.stderr
