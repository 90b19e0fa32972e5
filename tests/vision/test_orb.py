"""The ORB extractor's spatial distribution: per pyramid level, round robin over grid cells."""

from __future__ import annotations

import threading

import cv2
import numpy as np
import pytest

from evp.config import OrbSettings
from evp.runtime.parallel import HelperThreads
from evp.types import CameraModel
from evp.vision import orb as orb_module
from evp.vision.orb import CELL_PX, EDGE_PX, OrbExtractor, usable_levels


def _extractor(n_features: int = 500) -> OrbExtractor:
    camera = CameraModel(width=640, height=480, fx=500.0, fy=500.0, cx=320.0, cy=240.0)
    return OrbExtractor(OrbSettings(n_features=n_features), camera)


def _round_robin(extractor: OrbExtractor, xy: np.ndarray, octave: np.ndarray, response: np.ndarray) -> list[int]:
    """The rule spelled out with loops: per level, cells with a strong corner offer only strong
    ones; round k takes every cell's k-th strongest, strongest first (equal scores: by cell, row
    major); stop at the level's quota."""
    kept: list[int] = []
    ini = extractor.settings.ini_fast_threshold
    for level, quota in enumerate(extractor.level_quota):
        cells: dict[tuple[int, int], list[int]] = {}
        cell = CELL_PX * extractor.scale_factors[level]
        for i in np.flatnonzero(octave == level):
            cells.setdefault((int(xy[i, 1] // cell), int(xy[i, 0] // cell)), []).append(int(i))
        queues = []
        for key, members in cells.items():
            strong = [i for i in members if response[i] >= ini]
            queues.append((key, sorted(strong or members, key=lambda i: (-response[i], i))))
        chosen: list[int] = []
        for k in range(max((len(q) for _, q in queues), default=0)):
            chosen += [i for _, i in sorted(((key, q[k]) for key, q in queues if k < len(q)), key=lambda c: (-response[c[1]], c[0]))]
        kept += chosen[:quota]
    return kept


@pytest.mark.parametrize("seed", range(5))
def test_distribution_follows_the_round_robin_rule(seed):
    extractor = _extractor()
    rng = np.random.default_rng(seed)
    n = 4000
    octave = rng.integers(0, len(extractor.level_quota), n)
    xy = rng.uniform(0, [640, 480], (n, 2)) / extractor.scale_factors[octave][:, None]
    xy[: n // 2] *= 0.3  # crowd half of the corners into one corner of the image
    response = rng.integers(7, 60, n).astype(float)  # integer FAST scores: ties are common
    chosen = extractor._distribute(xy, octave, response)
    assert chosen.tolist() == _round_robin(extractor, xy, octave, response)
    counts = np.bincount(octave[chosen], minlength=len(extractor.level_quota))
    assert np.all(counts <= extractor.level_quota)


@pytest.mark.xfail(
    strict=True,
    reason="known limitation: OpenCV's detect keeps the 3 x n_features strongest FAST corners per level "
    "before our cell distribution runs, so a faint half of the image next to a strongly textured one "
    "loses its weak corners (ORB-SLAM runs FAST per cell instead)",
)
def test_features_spread_over_the_image_not_only_its_textured_part():
    rng = np.random.default_rng(3)
    image = np.full((480, 640), 128, np.uint8)
    image[:, :320] = rng.integers(0, 256, (480, 320), dtype=np.uint8)  # strong texture on the left
    right = cv2.GaussianBlur(rng.integers(0, 256, (480, 320), dtype=np.uint8), (0, 0), 2.0)
    image[:, 320:] = cv2.convertScaleAbs(right, alpha=0.8, beta=26)  # faint: FAST scores under 20 on the right
    features = _extractor(1000).extract(image)
    plain = cv2.ORB_create(1000).detect(image)
    share_right = np.mean(features.px[:, 0] > 340)
    share_right_plain = np.mean([k.pt[0] > 340 for k in plain])
    assert len(features) >= 900
    assert share_right > 0.2
    assert share_right > 3 * share_right_plain


@pytest.mark.parametrize(("size", "expected"), [((240, 180), 6), ((752, 480), 8), ((640, 380), 8), ((1226, 370), 8)])
def test_pyramid_keeps_only_levels_that_hold_a_grid_cell_inside_the_borders(size, expected):
    camera = CameraModel(width=size[0], height=size[1], fx=300.0, fy=300.0, cx=size[0] / 2, cy=size[1] / 2)
    settings = OrbSettings()
    levels = usable_levels(settings, camera)
    assert levels == expected
    coarsest = min(size) / settings.scale_factor ** (levels - 1)
    assert coarsest >= 2 * EDGE_PX + CELL_PX
    if levels < settings.pyramid_levels:
        assert coarsest / settings.scale_factor < 2 * EDGE_PX + CELL_PX
    assert usable_levels(OrbSettings(pyramid_levels=4), camera) == min(4, expected)
    extractor = OrbExtractor(settings, camera)
    assert len(extractor.scale_factors) == len(extractor.level_quota) == levels and extractor.level_quota.sum() == settings.n_features


def test_per_level_extraction_gives_the_features_of_one_opencv_pyramid():
    """Each level detected and described on its own (two threads) must keep what one OpenCV ORB
    over the whole pyramid keeps: the same corners per level, positions, angles, descriptors."""
    camera = CameraModel(width=240, height=180, fx=200.0, fy=200.0, cx=120.0, cy=90.0)
    image = cv2.GaussianBlur(np.random.default_rng(0).integers(0, 256, (180, 240), dtype=np.uint8), (0, 0), 1.2)
    helper = HelperThreads()
    extractor = OrbExtractor(OrbSettings(n_features=500), camera, helper)
    levels = len(extractor.scale_factors)
    pyramid = cv2.ORB_create(
        nfeatures=1500,
        scaleFactor=1.2,
        nlevels=levels,
        edgeThreshold=EDGE_PX,
        scoreType=cv2.ORB_FAST_SCORE,
        fastThreshold=extractor.settings.min_fast_threshold,
    )
    keypoints = pyramid.detect(image)
    xy = cv2.KeyPoint_convert(keypoints)
    octave = np.array([k.octave for k in keypoints])
    chosen = extractor._distribute(xy, octave, np.array([k.response for k in keypoints]))
    keypoints, descriptors = pyramid.compute(image, [keypoints[i] for i in chosen])
    ours = extractor.extract(image)
    assert len(ours) == len(keypoints) > 400
    theirs = cv2.KeyPoint_convert(keypoints)
    order_ours = np.lexsort((ours.px[:, 1], ours.px[:, 0], ours.octave))
    order_theirs = np.lexsort((theirs[:, 1], theirs[:, 0], [k.octave for k in keypoints]))
    np.testing.assert_allclose(ours.px[order_ours], theirs[order_theirs], atol=1e-3)
    np.testing.assert_array_equal(ours.octave[order_ours], np.array([k.octave for k in keypoints])[order_theirs])
    np.testing.assert_allclose(ours.angle[order_ours], np.array([k.angle for k in keypoints])[order_theirs], atol=1e-3)
    np.testing.assert_array_equal(ours.descriptors[order_ours], descriptors[order_theirs])
    assert set(ours.octave.tolist()) == set(range(levels))
    one_thread = OrbExtractor(OrbSettings(n_features=500), camera).extract(image)
    np.testing.assert_array_equal(one_thread.px, ours.px)
    np.testing.assert_array_equal(one_thread.descriptors, ours.descriptors)
    for _ in range(20):  # whichever thread takes a level, the features come out level by level
        again = extractor.extract(image)
        np.testing.assert_array_equal(again.px, ours.px)
        assert np.all(np.diff(again.octave) >= 0)
    helper.close()


def test_a_failure_in_the_helper_thread_is_raised_not_waited_for(monkeypatch):
    """The caller waits for the helper's pyramid: if building it fails, the error must come back
    to the caller instead of leaving it waiting."""
    helper = HelperThreads()
    camera = CameraModel(width=640, height=480, fx=500.0, fy=500.0, cx=320.0, cy=240.0)
    extractor = OrbExtractor(OrbSettings(n_features=500), camera, helper)
    image = np.full((480, 640), 128, np.uint8)

    def broken_resize(*args, **kwargs):
        raise cv2.error("resize failed")

    monkeypatch.setattr(orb_module.cv2, "resize", broken_resize)
    outcome: list[BaseException] = []
    worker = threading.Thread(target=lambda: outcome.append(pytest.raises(cv2.error, extractor.extract, image).value), daemon=True)
    worker.start()
    worker.join(timeout=10)
    assert not worker.is_alive() and len(outcome) == 1
    helper.close()


def test_features_are_kept_within_the_ray_cone_of_a_wide_fisheye():
    from evp.slam.projection import undistorted_bounds
    from evp.types import LensModel

    pinhole = _extractor()
    assert all(mask is None for mask in pinhole._level_masks)  # a pinhole keeps every feature
    assert undistorted_bounds(pinhole) == (0.0, 0.0, 639.0, 479.0)
    fisheye = CameraModel(640, 480, 254.6, 254.6, 319.5, 239.5, lens=LensModel.EQUIDISTANT)  # 180 degrees diagonal
    extractor = OrbExtractor(OrbSettings(n_features=1500), fisheye)
    image = cv2.resize(np.random.default_rng(0).integers(0, 255, (120, 160), dtype=np.uint8), (640, 480), interpolation=cv2.INTER_NEAREST)
    features = extractor.extract(image)
    angles = np.degrees(np.arccos(fisheye.bearings(features.px)[:, 2]))
    assert len(features) > 500 and angles.max() <= orb_module.MAX_RAY_ANGLE_DEG + 0.5
    assert angles.max() > orb_module.MAX_RAY_ANGLE_DEG - 5  # the cone, not the whole image, bounds them
    u_min, v_min, u_max, v_max = undistorted_bounds(extractor)
    reach = np.tan(np.radians(orb_module.MAX_RAY_ANGLE_DEG)) * fisheye.fx
    assert np.isfinite([u_min, v_min, u_max, v_max]).all()
    assert u_min == pytest.approx(fisheye.cx - reach) and u_max == pytest.approx(fisheye.cx + reach)
    assert np.all((features.un_px >= [u_min, v_min]) & (features.un_px <= [u_max, v_max]))
    # each keeps its lens Jacobian, whose weakest direction (radial) sets how far a search
    # window of detected pixels reaches in undistorted ones: 1 / cos^2(theta) on this lens
    assert np.allclose(features.lens_jacobian, fisheye.pixel_jacobian(features.normalised))
    theta = np.radians(angles)
    assert np.allclose(orb_module.window_stretch(features.lens_jacobian), 1 / np.cos(theta) ** 2, rtol=1e-6)
    assert pinhole.extract(image).lens_jacobian is None and orb_module.window_stretch(None) == 1.0
