"""The marker map of seed 003 (section 3.2.2): links, their quality, the grid, bad input, and the
pose-graph refinement."""

import numpy as np
import pytest

from evp.config import MarkerSettings
from evp.markers.detection import yaw_compensate
from evp.markers.marker_map import MarkerMap
from evp.markers.pose_graph import refine_poses
from tests.markers.synthetic import PITCH, grid_positions, observe


def _flown(markers, path, height=0.45, yaw=np.pi / 2) -> MarkerMap:
    marker_map = MarkerMap(MarkerSettings(), min_frames=2)
    for k, xy in enumerate(path):
        marker_map.update(k / 30, observe(np.asarray(xy), height, markers, yaw))
    return marker_map


def test_eq1_turns_view_port_coordinates_by_the_yaw():
    turned = yaw_compensate(np.array([[1.0, 0.0, 0.5]]), np.pi / 2)
    np.testing.assert_allclose(turned, [[0.0, -1.0, 0.5]], atol=1e-12)


@pytest.mark.parametrize("yaw", [np.pi / 2, np.pi / 2 + 0.6, -2.0])
def test_a_flight_over_a_grid_maps_every_marker_with_its_neighbours_and_grid_cell(yaw):
    markers = grid_positions()
    path = [(x, y) for y in np.linspace(0, 0.8, 9) for x in (np.linspace(0, 0.8, 20) if int(y * 10) % 2 == 0 else np.linspace(0.8, 0, 20))]
    marker_map = _flown(markers, path, yaw=yaw)
    assert set(marker_map.poses) == set(markers)
    assert marker_map.pitch_m == pytest.approx(PITCH, abs=1e-6)
    links = marker_map.adjacency[12]
    assert {way: link.neighbour for way, link in links.items()} == {"north": 17, "south": 7, "east": 13, "west": 11}
    grid = marker_map.grid()
    root = marker_map.root
    for marker_id, cell in grid.items():
        expected = np.round((markers[marker_id] - markers[root]) / PITCH).astype(int)
        assert cell == tuple(expected)
    for marker_id, pose in marker_map.poses.items():
        np.testing.assert_allclose(pose[:2], markers[marker_id] - markers[root], atol=1e-6)


def test_a_nearer_view_overwrites_a_worse_link_and_a_farther_one_does_not():
    markers = {0: np.zeros(2), 1: np.array([PITCH, 0.0])}
    marker_map = _flown(markers, [(0.1, 0.0)] * 3, height=0.6)
    far = marker_map.adjacency[0]["east"].quality
    marker_map.update(1.0, observe(np.array([0.1, 0.0]), 0.3, markers))
    near = marker_map.adjacency[0]["east"].quality
    marker_map.update(2.0, observe(np.array([0.1, 0.0]), 0.7, markers))
    assert near > far and marker_map.adjacency[0]["east"].quality == near


def test_a_marker_seen_in_one_frame_only_is_not_mapped():
    markers = grid_positions(3, 1)
    marker_map = _flown(markers, [(0.0, 0.0)] * 3)
    flicker = observe(np.array([0.0, 0.0]), 0.45, {**markers, 50: np.array([0.25, 0.1])})
    marker_map.update(1.0, flicker)
    assert 50 not in marker_map.poses
    marker_map.update(1.1, observe(np.array([0.0, 0.0]), 0.45, markers))  # gone again: told why it is not in the map
    assert any(e.kind == "unconfirmed_marker" and "marker 50" in e.detail for e in marker_map.events)


def test_a_marker_id_seen_in_two_places_is_rejected_and_logged():
    markers = grid_positions(3, 3)
    marker_map = _flown(markers, [(0.2, 0.2)] * 3)
    moved = dict(markers)
    moved[4] = markers[4] + np.array([0.0, 0.29])  # a second marker 4, elsewhere
    localisation = marker_map.update(1.0, observe(np.array([0.2, 0.2]), 0.45, moved))
    assert 4 not in localisation.marker_ids
    np.testing.assert_allclose(localisation.pose[:2], np.array([0.2, 0.2]) - markers[marker_map.root], atol=1e-6)
    assert any(e.kind == "duplicate_id" and "marker 4" in e.detail for e in marker_map.events)
    twice = observe(np.array([0.2, 0.2]), 0.45, markers) + observe(np.array([0.2, 0.2]), 0.45, {4: markers[4]})
    marker_map.update(2.0, twice)
    assert any(e.kind == "duplicate_id" and "[4]" in e.detail for e in marker_map.events)


def test_the_pose_graph_spreads_a_chain_error_over_a_loop():
    truth = {i: np.array([np.cos(a), np.sin(a), a + np.pi / 2]) for i, a in enumerate(np.linspace(0, 2 * np.pi, 9)[:-1])}
    edges = {}
    for i in range(8):
        j = (i + 1) % 8
        a, b = truth[i], truth[j]
        c, s = np.cos(a[2]), np.sin(a[2])
        d = b[:2] - a[:2]
        edges[(i, j)] = (np.array([c * d[0] + s * d[1], -s * d[0] + c * d[1], (b[2] - a[2] + np.pi) % (2 * np.pi) - np.pi]), 1.0)
    start = {i: p + (np.array([0.02 * i, -0.015 * i, 0.01 * i]) if i else 0) for i, p in truth.items()}
    refined = refine_poses(start, edges, fixed=0)
    before = max(np.linalg.norm(start[i][:2] - truth[i][:2]) for i in truth)
    after = max(np.linalg.norm(refined[i][:2] - truth[i][:2]) for i in truth)
    assert after < 1e-4 < before


def test_the_pose_graph_jacobian_is_the_residuals_derivative():
    from scipy.optimize import approx_fprime

    from evp.markers.pose_graph import relative_jacobian, relative_residuals

    rng = np.random.default_rng(0)
    poses = rng.normal(0, 1, (5, 3))
    pairs = np.array([[0, 1], [1, 2], [2, 3], [3, 4], [4, 0], [1, 3]])
    measured, weights = rng.normal(0, 1, (6, 3)), rng.uniform(0.5, 1.0, 6)

    def residuals(x):
        moved = poses.copy()
        moved[1:] = x.reshape(-1, 3)
        return relative_residuals(moved, pairs, measured, weights)

    numeric = np.array([approx_fprime(poses[1:].ravel(), lambda x, k=k: residuals(x)[k], 1e-7) for k in range(18)])
    analytic = relative_jacobian(poses, pairs, weights, np.array([-1, 0, 1, 2, 3])).toarray()
    np.testing.assert_allclose(analytic, numeric, atol=1e-5)


def test_a_lone_mapped_marker_far_from_where_the_motion_puts_the_camera_is_rejected_and_logged():
    markers = grid_positions(3, 3)
    marker_map = _flown(markers, [(0.2, 0.2)] * 3)
    copy = {4: markers[4]}  # a second marker 4, seen alone with the camera 0.35 m from it
    camera = markers[4] + np.array([0.0, 0.0]) - markers[marker_map.root]
    assert marker_map.update(1.0, observe(markers[4], 0.45, copy), expected_xy=camera + np.array([0.35, 0.0])) is None
    assert any(e.kind == "duplicate_id" and "only mapped one" in e.detail for e in marker_map.events)
    assert marker_map.update(1.1, observe(markers[4], 0.45, copy), expected_xy=camera + np.array([0.02, 0.0])) is not None
