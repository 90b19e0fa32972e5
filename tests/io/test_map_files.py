"""The map file (``map.npz``): a round trip (the georeference too), bounded reading however many
keyframes, and a clear error for a file that is not a map."""

import json
from collections import Counter

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from evp.errors import EvpError
from evp.fusion.map_georeference import MapGeoreference
from evp.io.map_files import load_map, read_map_georeference, save_map
from evp.slam.map import Map
from evp.vision.orb import Features
from evp.vision.vocabulary import BowVector

SCALES = 1.2 ** np.arange(8)


def _map(keyframes: int, features: int, rng: np.random.Generator) -> Map:
    """Keyframes along a line looking at points 2 m ahead, each point seen by 3 keyframes."""
    slam_map = Map()
    points = rng.uniform([-1, -1, 1.5], [1, 1, 2.5], (keyframes + 2, 3))
    for k in range(keyframes):
        px = rng.uniform(0, 640, (features, 2))
        normalised = (px - [320, 190]) / 500.0
        feats = Features(
            px, px.copy(), normalised, rng.integers(0, 8, features), rng.uniform(0, 360, features), rng.integers(0, 256, (features, 32), dtype=np.uint8)
        )
        T_cw = np.eye(4)
        T_cw[0, 3] = -0.05 * k
        words = np.sort(rng.choice(1000, 40, replace=False)).astype(np.int32)
        slam_map.add_keyframe(float(k), T_cw, feats, BowVector(words, np.full(40, 1 / 40)))
    for i, position in enumerate(points):
        point = slam_map.add_point(position, rng.integers(0, 256, 32, dtype=np.uint8), max(0, i - 2))
        for k in range(max(0, i - 2), min(keyframes, i + 1)):
            slam_map.add_observation(point, slam_map.keyframes[k], i % features)
    for kf in slam_map.keyframes.values():
        slam_map.update_covisibility(kf)
    slam_map.refresh_points(list(slam_map.points), SCALES)
    return slam_map


def test_a_saved_map_loads_back_the_same(tmp_path):
    original = _map(12, 50, np.random.default_rng(0))
    save_map(original, tmp_path / "map.npz")
    loaded = load_map(tmp_path / "map.npz", SCALES)
    assert sorted(loaded.keyframes) == sorted(original.keyframes)
    assert sorted(loaded.points) == sorted(original.points)
    for point_id, point in original.points.items():
        assert np.allclose(loaded.points[point_id].position, point.position)
        assert loaded.points[point_id].observations == point.observations
    for kf_id, kf in original.keyframes.items():
        assert np.array_equal(loaded.keyframes[kf_id].point_ids, kf.point_ids)
        assert np.array_equal(loaded.keyframes[kf_id].features.descriptors, kf.features.descriptors)
        assert np.allclose(loaded.keyframes[kf_id].T_cw, kf.T_cw)
        assert np.array_equal(loaded.keyframes[kf_id].bow.words, kf.bow.words) and np.allclose(loaded.keyframes[kf_id].bow.weights, kf.bow.weights)
    # the place-recognition database is rebuilt: a keyframe's own vector finds it first
    for kf_id, kf in original.keyframes.items():
        assert loaded.database.relocalisation_candidates(kf.bow, loaded.keyframes, 1) == [kf_id]


def test_a_distorting_lens_keeps_its_jacobians_and_a_map_without_them_weighs_as_before(tmp_path):
    """Each feature's lens Jacobian (how its noise is weighed) is saved with it; a map of an
    undistorted camera has none, so its bundle adjustment weighs by pyramid level alone."""
    original = _map(6, 20, np.random.default_rng(2))
    assert original.gather_lens_jacobians(np.array([0, 1]), np.array([3, 4])) is None
    for kf in original.keyframes.values():
        kf.features.lens_jacobian = np.random.default_rng(kf.id).uniform(0.2, 1.0, (len(kf.features), 2, 2))
    save_map(original, tmp_path / "map.npz")
    loaded = load_map(tmp_path / "map.npz", SCALES)
    for kf_id, kf in original.keyframes.items():
        assert np.array_equal(loaded.keyframes[kf_id].features.lens_jacobian, kf.features.lens_jacobian)
    gathered = loaded.gather_lens_jacobians(np.array([2, 0, 2]), np.array([5, 1, 7]))
    assert np.array_equal(gathered[0], original.keyframes[2].features.lens_jacobian[5])
    assert np.array_equal(gathered[1], original.keyframes[0].features.lens_jacobian[1])


def test_each_array_is_read_from_the_file_once_however_many_keyframes(tmp_path, monkeypatch):
    """Indexing an ``np.load`` archive decompresses the whole array each time: read per keyframe,
    a 520-keyframe map took 26 GB to load. Reads must not grow with the keyframes."""
    save_map(_map(40, 30, np.random.default_rng(1)), tmp_path / "map.npz")
    reads: Counter[str] = Counter()
    archive_type = type(np.load(tmp_path / "map.npz"))
    original_getitem = archive_type.__getitem__

    def counting_getitem(self, key):
        reads[key] += 1
        return original_getitem(self, key)

    monkeypatch.setattr(archive_type, "__getitem__", counting_getitem)
    loaded = load_map(tmp_path / "map.npz", SCALES)
    assert len(loaded.keyframes) == 40
    assert reads and max(reads.values()) == 1, reads.most_common(3)


@pytest.mark.parametrize(
    "content",
    [b"", b"not a zip archive at all", b"PK\x03\x04truncated"],
    ids=["empty", "text", "truncated zip"],
)
def test_a_file_that_is_not_a_map_is_a_clear_error(tmp_path, content):
    path = tmp_path / "map.npz"
    path.write_bytes(content)
    with pytest.raises(EvpError, match="not an EVP map file"):
        load_map(path, SCALES)


def test_a_map_of_an_older_format_is_refused_by_name(tmp_path):
    save_map(_map(3, 10, np.random.default_rng(3)), tmp_path / "map.npz")
    with np.load(tmp_path / "map.npz") as archive:
        arrays = {name: archive[name] for name in archive.files}
    arrays["meta"] = np.array(json.dumps({**json.loads(str(arrays["meta"])), "version": 1}))
    np.savez(tmp_path / "old.npz", **arrays)
    with pytest.raises(EvpError, match="map format version 1"):
        load_map(tmp_path / "old.npz", SCALES)


def test_a_map_cut_short_is_a_clear_error(tmp_path):
    save_map(_map(5, 20, np.random.default_rng(2)), tmp_path / "map.npz")
    whole = (tmp_path / "map.npz").read_bytes()
    (tmp_path / "cut.npz").write_bytes(whole[: len(whole) // 2])
    with pytest.raises(EvpError, match="not an EVP map file"):
        load_map(tmp_path / "cut.npz", SCALES)


def _georeference() -> MapGeoreference:
    R = Rotation.from_euler("zyx", [40.0, 2.0, 179.0], degrees=True).as_matrix()
    return MapGeoreference(3.05, R, np.array([12.5, -3.0, 61.0]), (43.7238, 10.3966, 4.0), 1.5, 0.012, 0.012, 84, 0.41)


def test_the_georeference_comes_back_with_the_map(tmp_path):
    """A georeferenced run's map keeps its similarity to ENU and the ENU origin; a map saved
    without one (or of version 2, before maps had one) reads back as not georeferenced."""
    georeference = _georeference()
    save_map(_map(12, 50, np.random.default_rng(0)), tmp_path / "map.npz", georeference)
    loaded = read_map_georeference(tmp_path / "map.npz")
    assert loaded.scale == georeference.scale and loaded.origin == georeference.origin
    assert np.array_equal(loaded.R, georeference.R) and np.array_equal(loaded.t, georeference.t)
    assert (loaded.translation_sigma_m, loaded.rotation_sigma_rad, loaded.log_scale_sigma) == (1.5, 0.012, 0.012)
    assert (loaded.keyframes, loaded.residual_m) == (84, 0.41)
    assert len(load_map(tmp_path / "map.npz", SCALES).keyframes) == 12
    save_map(_map(3, 10, np.random.default_rng(3)), tmp_path / "plain.npz")
    assert read_map_georeference(tmp_path / "plain.npz") is None
    _rewrite_meta(tmp_path / "plain.npz", tmp_path / "v2.npz", version=2, georeference=None)
    assert read_map_georeference(tmp_path / "v2.npz") is None and len(load_map(tmp_path / "v2.npz", SCALES).keyframes) == 3


@pytest.mark.parametrize(
    "change",
    [{"scale": -1.0}, {"R": [[2, 0, 0], [0, 1, 0], [0, 0, 1]]}, {"origin": [43.7, 10.4]}, {"t": [0, float("nan"), 0]}],
    ids=["negative scale", "not a rotation", "origin without altitude", "NaN"],
)
def test_a_malformed_georeference_is_a_clear_error(tmp_path, change):
    save_map(_map(3, 10, np.random.default_rng(3)), tmp_path / "map.npz", _georeference())
    _rewrite_meta(tmp_path / "map.npz", tmp_path / "bad.npz", georeference={**_georeference().to_json(), **change})
    with pytest.raises(EvpError, match="georeference is malformed"):
        read_map_georeference(tmp_path / "bad.npz")


def _rewrite_meta(source, target, **changes) -> None:
    with np.load(source) as archive:
        arrays = {name: archive[name] for name in archive.files}
    arrays["meta"] = np.array(json.dumps({**json.loads(str(arrays["meta"])), **changes}))
    np.savez(target, **arrays)
