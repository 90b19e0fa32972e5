"""The final whole-map adjustment on a small exact map: the poses set on each keyframe's longest
tracks, the other points adjusted on them."""

import numpy as np

from evp.slam.map import Map
from evp.slam.map_adjustment import adjust_whole_map, long_track_points
from evp.vision.orb import Features
from evp.vision.vocabulary import BowVector

K = np.array([[450.0, 0, 320], [0, 450.0, 190], [0, 0, 1]])
SCALES = 1.2 ** np.arange(8)


def _camera_pose(k: int) -> np.ndarray:
    T = np.eye(4)
    T[:3, 3] = [-0.2 * k, 0.02 * k, 0.0]
    return T


def _exact_map(rng: np.random.Generator, keyframes: int = 6, points: int = 240) -> tuple[Map, np.ndarray]:
    """Keyframes moving sideways over points 4-6 m ahead; point i is seen by keyframes
    ``first .. first + length - 1`` with track lengths from 2 to all keyframes. Every observation
    exact, at level 0."""
    positions = rng.uniform([-1.5, -1.0, 4.0], [2.5, 1.0, 6.0], (points, 3))
    lengths = rng.integers(2, keyframes + 1, points)
    firsts = np.array([rng.integers(0, keyframes - n + 1) for n in lengths])
    slam_map = Map()
    for k in range(keyframes):
        T = _camera_pose(k)
        pc = positions @ T[:3, :3].T + T[:3, 3]
        normalised = pc[:, :2] / pc[:, 2:3]
        px = normalised @ K[:2, :2].T + K[:2, 2]
        features = Features(px, px.copy(), normalised, np.zeros(points, int), np.zeros(points), rng.integers(0, 256, (points, 32), dtype=np.uint8))
        slam_map.add_keyframe(float(k), T, features, BowVector(np.arange(4, dtype=np.int32), np.full(4, 0.25)))
    for i, position in enumerate(positions):
        point = slam_map.add_point(position, rng.integers(0, 256, 32, dtype=np.uint8), int(firsts[i]))
        for k in range(firsts[i], firsts[i] + lengths[i]):
            slam_map.add_observation(point, slam_map.keyframes[k], i)
    for kf in slam_map.keyframes.values():
        slam_map.update_covisibility(kf)
    slam_map.refresh_points(list(slam_map.points), SCALES)
    return slam_map, positions


def test_each_keyframe_keeps_its_longest_tracks():
    slam_map, _ = _exact_map(np.random.default_rng(4))
    kept = set(long_track_points(slam_map, 10))
    length = {p: len(point.observations) for p, point in slam_map.points.items()}
    tenth_longest = {}
    for k, kf in slam_map.keyframes.items():
        ids = [int(p) for p in kf.point_ids if p >= 0]
        assert sum(p in kept for p in ids) >= 10
        tenth_longest[k] = sorted((length[p] for p in ids), reverse=True)[9]
    for p in kept:  # a kept point is among the ten longest tracks of some keyframe seeing it
        assert length[p] >= min(tenth_longest[k] for k in slam_map.points[p].observations)
    assert len(kept) < len(slam_map.points)  # short tracks were left out
    assert set(long_track_points(slam_map, 10_000)) == set(slam_map.points)  # fewer than asked: all


def test_the_points_left_out_are_adjusted_on_the_poses_the_long_tracks_set():
    rng = np.random.default_rng(5)
    slam_map, positions = _exact_map(rng)
    left_out = sorted(set(slam_map.points) - set(long_track_points(slam_map, 20)))
    assert left_out
    slam_map.store.position[left_out] += rng.normal(0, 0.01, (len(left_out), 3))  # short tracks off by ~1 px
    adjust_whole_map(slam_map, SCALES, K, evaluations=20, points_per_keyframe=20)
    for k, kf in slam_map.keyframes.items():
        assert np.abs(kf.T_cw - _camera_pose(k)).max() < 1e-6  # the long tracks were exact: poses stay
    assert np.abs(slam_map.store.position[left_out] - positions[left_out]).max() < 1e-5
    assert all(len(slam_map.points[p].observations) >= 2 for p in left_out)  # no observation dropped
