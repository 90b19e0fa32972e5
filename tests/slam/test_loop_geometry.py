"""Loop closing's geometry on exact data: the similarity between two cameras from matched
points, and the pose graph spreading a loop's error."""

import numpy as np
from scipy.spatial.transform import Rotation

from evp.geometry.alignment import umeyama
from evp.geometry.sim3 import Sim3
from evp.optim.reprojection import pinhole_pixels
from evp.slam.essential_graph import optimise_pose_graph
from evp.slam.loop_closing import _Candidate, _corrections_agree
from evp.slam.sim3_estimation import estimate_sim3

K = np.array([[400.0, 0, 320], [0, 400.0, 190], [0, 0, 1]])


def test_similarity_between_two_cameras_from_noisy_matches_with_outliers():
    rng = np.random.default_rng(1)
    Xa = np.c_[rng.uniform(-2, 2, (150, 2)), rng.uniform(3, 8, 150)]
    truth = Sim3.one(0.7, Rotation.from_rotvec([0.05, -0.2, 0.1]).as_matrix(), [0.4, -0.1, 0.3])
    Xb = truth.inverse().apply(Xa)
    uv_a, uv_b = pinhole_pixels(Xa, K) + rng.normal(0, 0.5, (150, 2)), pinhole_pixels(Xb, K) + rng.normal(0, 0.5, (150, 2))
    # the map's depths are noisy (a monocular map), and a third of the matches are wrong
    Xa_noisy = Xa * (1 + rng.normal(0, 0.01, (150, 1)))
    wrong = rng.choice(150, 50, replace=False)
    Xb_noisy = Xb.copy()
    Xb_noisy[wrong] = Xb[rng.permutation(wrong)]
    uv_b[wrong] = uv_b[rng.permutation(wrong)]
    ones = np.ones(150)
    S, inliers = estimate_sim3(Xa_noisy, Xb_noisy, uv_a, uv_b, ones, ones, K)
    assert inliers[np.setdiff1d(np.arange(150), wrong)].mean() > 0.9 and inliers[wrong].mean() < 0.1
    assert abs(S.s[0] / 0.7 - 1) < 0.01
    assert np.degrees(np.linalg.norm(Rotation.from_matrix(S.R[0] @ truth.R[0].T).as_rotvec())) < 0.2


def test_unrelated_points_give_no_similarity():
    rng = np.random.default_rng(2)
    Xa = np.c_[rng.uniform(-2, 2, (60, 2)), rng.uniform(3, 8, 60)]
    Xb = np.c_[rng.uniform(-2, 2, (60, 2)), rng.uniform(3, 8, 60)]
    ones = np.ones(60)
    assert estimate_sim3(Xa, Xb, pinhole_pixels(Xa, K), pinhole_pixels(Xb, K), ones, ones, K) is None


def drifting_circle_graph(n: int = 20):
    """Poses around a circle whose odometry edges drift 1 % in scale per step, and an exact loop
    edge: (centres, initial, fixed, edge_i, edge_j, measured)."""
    angles = np.linspace(0, 2 * np.pi, n, endpoint=False)
    R_cw = Rotation.from_euler("z", -angles[:, None]).as_matrix()
    centres = np.c_[3 * np.cos(angles), 3 * np.sin(angles), np.zeros(n)]
    truth = Sim3(np.ones(n), R_cw, -np.einsum("nij,nj->ni", R_cw, centres))
    rel = [truth[i] @ truth[i - 1].inverse() for i in range(1, n)]
    drifted = [truth[0]]
    for i, r in enumerate(rel):
        step = Sim3(r.s, r.R, r.t * 1.01 ** (i + 1))  # the map's scale slips
        drifted.append(step @ drifted[-1])
    initial = Sim3.stack(drifted)
    edge_i = np.r_[np.arange(1, n), 0]
    edge_j = np.r_[np.arange(0, n - 1), n - 1]
    measured_odometry = initial[edge_i[:-1]] @ initial[edge_j[:-1]].inverse()
    loop = truth[[0]] @ truth[[n - 1]].inverse()
    measured = Sim3.stack([measured_odometry, loop])
    fixed = np.arange(n) == 0
    return centres, initial, fixed, edge_i, edge_j, measured


def test_pose_graph_spreads_a_loop_error_in_pose_and_scale():
    n = 20
    centres, initial, fixed, edge_i, edge_j, measured = drifting_circle_graph(n)

    def loop_gap(poses):
        return np.linalg.norm((measured[[n - 1]].inverse() @ poses[[0]] @ poses[[n - 1]].inverse()).log())

    optimised = optimise_pose_graph(initial, fixed, edge_i, edge_j, measured)
    assert loop_gap(initial) > 0.1
    assert loop_gap(optimised) < 0.25 * loop_gap(initial)
    np.testing.assert_allclose(optimised[[0]].t, initial[[0]].t)  # the fixed pose stays

    def centre_error(poses):  # after similarity alignment, as ATE
        estimated = poses.inverse().t
        aligned = umeyama(estimated, centres, with_scale=True).apply(estimated)
        return np.sqrt(np.mean(np.sum((aligned - centres) ** 2, axis=1)))

    assert centre_error(optimised) < 0.6 * centre_error(initial)


def _measured(rotvec_deg, std_deg):
    """A loop verification of a keyframe: the correction it measured and how well."""
    return _Candidate(None, None, {}, Rotation.from_rotvec(rotvec_deg, degrees=True).as_matrix(), std_deg)


def test_a_loop_is_closed_when_keyframes_in_a_row_measure_the_same_correction():
    # seed 3 of the rendered circle: one drift measured three times (0.4-0.8 degrees apart)
    assert _corrections_agree([_measured([1.64, -2.66, 2.57], 0.3), _measured([1.82, -2.73, 2.26], 0.3), _measured([2.41, -2.17, 2.54], 0.3)])
    # seed 1: a correction measured through points the map holds badly, sliding as overlap grows
    assert not _corrections_agree([_measured([17.18, 2.75, 0.18], 0.3), _measured([15.14, 2.4, 0.4], 0.3), _measured([14.53, 3.28, 0.5], 0.3)])
    # the tolerance is the measurements' own uncertainty: coarser ones may differ more
    apart = [_measured([0, 0, 0], 0.3), _measured([0, 0, 1.5], 0.3), _measured([0, 0, 0.8], 0.3)]
    assert not _corrections_agree(apart)
    assert _corrections_agree([_measured([0, 0, angle], 0.6) for angle in (0, 1.5, 0.8)])
