"""Survey bundle adjustment on exact synthetic photos: two flight lines over gently uneven ground,
taken through a barrel-distorting lens the nominal camera knows nothing about."""

from dataclasses import replace

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from evp.geometry.alignment import umeyama
from evp.geometry.transforms import se3
from evp.optim.self_calibration import self_calibrating_adjust
from evp.types import CameraModel
from evp.vo import survey_adjustment
from evp.vo.survey_adjustment import adjust_survey, tracks_from_matches

NOMINAL = CameraModel(width=1200, height=900, fx=700.0, fy=700.0, cx=599.5, cy=449.5, name="exif_nominal")
TRUE_K1 = -0.05
DOWN = np.diag([1.0, -1.0, -1.0])  # camera z down, image x along world x


def _survey(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Ground points with +-3 m of relief and camera-to-world poses at ~120 m: two lines of 8
    photos 35 m apart, the second flown back (heading 180 degrees), gimbal within 2 degrees."""
    points = np.column_stack([rng.uniform(-100, 360, 1200), rng.uniform(-60, 230, 1200), rng.uniform(-3, 3, 1200)])
    poses = []
    for line, (y, heading) in enumerate([(60.0, 0.0), (170.0, 180.0)]):
        for k in range(8):
            x = 35.0 * k if line == 0 else 35.0 * (7 - k)
            tilt = Rotation.from_euler("xyz", [*rng.uniform(-2, 2, 2), heading], degrees=True).as_matrix()
            poses.append(se3(tilt @ DOWN, [x, y, 120.0 + rng.uniform(-1, 1)]))
    return points, np.array(poses)


def _observe(
    points: np.ndarray, poses: np.ndarray, rng: np.random.Generator, lens: CameraModel = replace(NOMINAL, k1=TRUE_K1), noise_px: float = 0.3
) -> tuple[list[np.ndarray], list[tuple[int, int, np.ndarray]]]:
    """Each photo's keypoints through ``lens`` (with ``noise_px`` of noise) and the matches between
    every pair sharing points."""
    seen_ids, keypoints = [], []
    for pose in poses:
        camera_points = (points - pose[:3, 3]) @ pose[:3, :3]
        pixels = lens.project(camera_points)
        inside = (pixels[:, 0] > 0) & (pixels[:, 0] < 1199) & (pixels[:, 1] > 0) & (pixels[:, 1] < 899)
        seen_ids.append(np.flatnonzero(inside))
        keypoints.append(pixels[inside] + rng.normal(0, noise_px, (inside.sum(), 2)))
    matches = []
    for i in range(len(poses)):
        for j in range(i):
            common, in_i, in_j = np.intersect1d(seen_ids[i], seen_ids[j], return_indices=True)
            if len(common) >= 20:
                matches.append((i, j, np.column_stack([in_i, in_j])))
    return keypoints, matches


def _corner_distortion(lens: CameraModel) -> float:
    """The radial distortion's relative shift at the image corner (k1 r^2 + k2 r^4)."""
    r2 = ((lens.width - 1 - lens.cx) / lens.fx) ** 2 + ((lens.height - 1 - lens.cy) / lens.fy) ** 2
    return lens.k1 * r2 + lens.k2 * r2 * r2


def test_tracks_join_pairwise_matches_and_drop_ambiguous_chains():
    keypoints = [np.zeros((3, 2)), np.ones((3, 2)), np.full((3, 2), 2.0)]
    # 0:0-1:0-2:0 is one track; 0:1-1:1-2:1 and 2:2-1:1 would put two keypoints of photo 2 in one track
    matches = [(1, 0, np.array([[0, 0], [1, 1]])), (2, 1, np.array([[0, 0], [1, 1], [2, 1]]))]
    tracks = tracks_from_matches(keypoints, matches)
    assert tracks.num_tracks == 1
    assert sorted(tracks.image_index.tolist()) == [0, 1, 2]


@pytest.mark.parametrize("seed", [0, 1])
def test_self_calibrates_the_lens_and_recovers_poses_from_rough_mosaic_poses(seed):
    rng = np.random.default_rng(seed)
    points, truth = _survey(rng)
    keypoints, matches = _observe(points, truth, rng)
    # what a mosaic gives: level cameras, heights off by up to 5 %, positions off by metres
    rough = truth.copy()
    for pose in rough[1:]:
        heading = np.arctan2(pose[1, 0], pose[0, 0])
        pose[:3, :3] = Rotation.from_euler("z", heading).as_matrix() @ DOWN
        pose[:3, 3] += [*rng.normal(0, 2.0, 2), rng.uniform(-6, 6)]
    adjusted, lens = adjust_survey(NOMINAL, rough, tracks_from_matches(keypoints, matches))
    assert abs(lens.fx / NOMINAL.fx - 1.0) < 0.02  # the +-3 m of relief is what tells focal length from height
    assert abs(_corner_distortion(lens) - _corner_distortion(replace(NOMINAL, k1=TRUE_K1))) < 0.006  # 4.5 px at the corner
    alignment = umeyama(adjusted[:, :3, 3], truth[:, :3, 3], with_scale=True)
    errors = np.linalg.norm(alignment.apply(adjusted[:, :3, 3]) - truth[:, :3, 3], axis=1)
    rough_errors = np.linalg.norm(umeyama(rough[:, :3, 3], truth[:, :3, 3], True).apply(rough[:, :3, 3]) - truth[:, :3, 3], axis=1)
    # one pixel is 0.17 m on the ground; the focal length comes out within 1 % (seed 0: 706.2 px for 700), 0.20 m at worst
    assert errors.max() < 0.25 < 2.0 < rough_errors.max()


def test_a_lens_unlike_the_nominal_one_is_recovered_in_one_adjustment(monkeypatch):
    """Exact photos through a lens 10 % longer than EXIF's, with barrel distortion: the focal length,
    k1 and k2 come out of the one adjustment (no lens search around it), as exactly as the lens
    priors let them over +-3 m of relief (their pull: 0.3 % of the focal length)."""
    rng = np.random.default_rng(5)
    points, truth = _survey(rng)
    true_lens = replace(NOMINAL, fx=770.0, fy=770.0, k1=-0.08, k2=0.03)
    keypoints, matches = _observe(points, truth, rng, true_lens, noise_px=0.0)
    adjustments = []
    monkeypatch.setattr(survey_adjustment, "bundle_adjust", lambda *args, **kwargs: pytest.fail("a lens search"))
    monkeypatch.setattr(survey_adjustment, "self_calibrating_adjust", lambda problem: adjustments.append(problem) or self_calibrating_adjust(problem))
    adjusted, lens = adjust_survey(NOMINAL, truth, tracks_from_matches(keypoints, matches))
    assert len(adjustments) == 1
    assert lens.fx == pytest.approx(770.0, rel=0.004) and lens.fy == lens.fx
    assert (lens.k1, lens.k2) == pytest.approx((-0.08, 0.03), abs=5e-4)
    alignment = umeyama(adjusted[:, :3, 3], truth[:, :3, 3], with_scale=True)  # the first photo holds six of the seven gauge freedoms
    assert np.abs(alignment.apply(adjusted[:, :3, 3]) - truth[:, :3, 3]).max() < 0.05


def test_a_calibrated_lens_is_kept():
    rng = np.random.default_rng(3)
    points, truth = _survey(rng)
    keypoints, matches = _observe(points, truth, rng)
    calibrated = replace(NOMINAL, k1=TRUE_K1, name="calibrated")
    adjusted, lens = adjust_survey(calibrated, truth, tracks_from_matches(keypoints, matches))
    assert lens is calibrated
    assert np.abs(adjusted[:, :3, 3] - truth[:, :3, 3]).max() < 0.1


def test_photos_without_matched_points_keep_their_poses():
    poses = np.repeat(se3(DOWN, [0.0, 0.0, 120.0])[None], 2, axis=0)
    poses[1, 0, 3] = 35.0
    no_tracks = tracks_from_matches([np.zeros((3, 2)), np.zeros((2, 2))], [(1, 0, np.zeros((0, 2), int))])
    adjusted, lens = adjust_survey(NOMINAL, poses, no_tracks)
    assert no_tracks.num_tracks == 0
    assert np.array_equal(adjusted, poses) and lens is NOMINAL
