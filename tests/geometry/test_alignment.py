"""Umeyama alignment on exact point sets: it recovers a known similarity or rigid motion, always
returns a proper rotation, flags collinear points and rejects input it cannot align."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from evp.errors import EvaluationError
from evp.geometry.alignment import Similarity, umeyama

TURN = Rotation.from_euler("xyz", [10, -20, 30], degrees=True).as_matrix()


def test_umeyama_recovers_a_known_similarity():
    rng = np.random.default_rng(0)
    points = rng.normal(size=(100, 3))
    truth = Similarity(Rotation.from_euler("xyz", [10, -20, 30], degrees=True).as_matrix(), np.array([1.0, -2.0, 3.0]), 2.5)
    found = umeyama(points, truth.apply(points), with_scale=True)
    assert np.allclose(found.rotation, truth.rotation, atol=1e-12)
    assert np.allclose(found.translation, truth.translation, atol=1e-12)
    assert found.scale == pytest.approx(2.5, abs=1e-12)


def test_umeyama_on_collinear_points_is_flagged_but_still_fits():
    line = np.column_stack([np.arange(10.0), np.zeros(10), np.zeros(10)])
    target = 2.0 * line[:, [1, 0, 2]] + [1.0, 2.0, 3.0]  # the line turned onto the y axis, scaled
    found = umeyama(line, target, with_scale=True)
    assert found.degenerate
    assert found.scale == pytest.approx(2.0)
    assert np.allclose(found.apply(line), target, atol=1e-12)
    with pytest.raises(EvaluationError, match="coincide"):
        umeyama(np.ones((5, 3)), np.ones((5, 3)), with_scale=True)


def test_rigid_alignment_keeps_scale_one_and_finds_the_rotation():
    points = np.random.default_rng(1).normal(size=(50, 3))
    truth = Similarity(TURN, np.array([0.5, 0.0, -1.0]), 1.0)
    found = umeyama(points, truth.apply(points), with_scale=False)
    assert found.scale == 1.0 and not found.degenerate
    assert np.allclose(found.rotation, TURN, atol=1e-12) and np.allclose(found.translation, truth.translation, atol=1e-12)
    shrunk = umeyama(points, Similarity(TURN, np.zeros(3), 0.5).apply(points), with_scale=False)
    assert shrunk.scale == 1.0 and np.allclose(shrunk.rotation, TURN, atol=1e-12)  # the rotation does not depend on scale


def test_a_mirrored_target_still_gives_a_proper_rotation():
    points = np.random.default_rng(2).normal(size=(30, 3))
    mirrored = points * [1.0, 1.0, -1.0]
    found = umeyama(points, mirrored, with_scale=True)
    assert np.linalg.det(found.rotation) == pytest.approx(1.0)
    assert np.allclose(found.rotation @ found.rotation.T, np.eye(3), atol=1e-12)


def test_poses_are_turned_and_moved_by_the_similarity():
    poses = np.repeat(np.eye(4)[None], 2, axis=0)
    poses[1, :3, 3] = [1.0, 0.0, 0.0]
    moved = Similarity(TURN, np.array([0.0, 2.0, 0.0]), 3.0).apply_to_poses(poses)
    assert np.allclose(moved[:, :3, :3], TURN)
    assert np.allclose(moved[1, :3, 3], 3.0 * TURN[:, 0] + [0.0, 2.0, 0.0])
    assert np.array_equal(poses[1, :3, :3], np.eye(3))  # the input is not changed
    assert np.array_equal(Similarity.identity().apply(poses[:, :3, 3]), poses[:, :3, 3])


@pytest.mark.parametrize(
    "source, target, message",
    [
        (np.zeros((5, 3)), np.zeros((4, 3)), "equal shape"),
        (np.zeros(5), np.zeros(5), "equal shape"),
        (np.array([[0.0, 0, 0], [1, np.nan, 0]]), np.zeros((2, 3)), "finite"),
        (np.zeros((1, 3)), np.zeros((1, 3)), "at least 2"),
    ],
)
def test_input_it_cannot_align_is_a_clear_error(source, target, message):
    with pytest.raises(EvaluationError, match=message):
        umeyama(source, target, with_scale=True)
