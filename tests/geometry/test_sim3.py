"""Similarity algebra in stacks (loop closing's Sim3): composition, inverse, log/exp, and the
rigid pose a similarity leaves a keyframe with."""

import numpy as np
from scipy.spatial.transform import Rotation

from evp.geometry.sim3 import Sim3


def _random_sim3(rng, n):
    return Sim3(np.exp(rng.normal(0, 0.2, n)), Rotation.random(n, random_state=rng).as_matrix(), rng.normal(0, 1, (n, 3)))


def _pixels(points_cam: np.ndarray) -> np.ndarray:
    return points_cam[:, :2] / points_cam[:, 2:3]


def test_similarity_algebra_round_trips():
    rng = np.random.default_rng(0)
    a, b = _random_sim3(rng, 5), _random_sim3(rng, 5)
    x = rng.normal(0, 1, (5, 3))
    np.testing.assert_allclose((a @ b).apply(x), a.apply(b.apply(x)), atol=1e-12)
    np.testing.assert_allclose((a.inverse() @ a).log(), 0, atol=1e-12)
    np.testing.assert_allclose(Sim3.exp(a.log()).R, a.R, atol=1e-12)
    np.testing.assert_allclose(Sim3.exp(a.log()).s, a.s, rtol=1e-12)
    # the rigid pose of a similarity projects points corrected by it as before
    T = a.to_se3()[0]
    point = np.array([0.3, -0.2, 4.0])
    corrected = a[0].inverse().apply(point[None])[0]
    np.testing.assert_allclose(_pixels((T[:3, :3] @ corrected + T[:3, 3])[None]), _pixels(point[None]), atol=1e-12)


def test_rigid_poses_are_similarities_of_scale_one():
    rng = np.random.default_rng(1)
    T = np.repeat(np.eye(4)[None], 3, axis=0)
    T[:, :3, :3] = Rotation.random(3, random_state=rng).as_matrix()
    T[:, :3, 3] = rng.normal(0, 1, (3, 3))
    S = Sim3.from_se3(T)
    assert np.array_equal(S.s, np.ones(3)) and np.allclose(S.to_se3(), T)
    assert len(Sim3.from_se3(T[0])) == 1


def test_stacks_are_indexed_and_joined_in_order():
    rng = np.random.default_rng(2)
    a, b = _random_sim3(rng, 2), _random_sim3(rng, 3)
    joined = Sim3.stack([a, b])
    assert len(joined) == 5
    assert np.array_equal(joined[3].t, b[1].t) and np.array_equal(joined[-1].R, b.R[-1:])
    assert np.array_equal(joined[1:3].s, np.r_[a.s[1], b.s[0]])
    one = Sim3.one(2.0, np.eye(3), [1.0, 0.0, 0.0])
    assert np.allclose(one.apply(np.array([[1.0, 1.0, 1.0]])), [[3.0, 2.0, 2.0]])
