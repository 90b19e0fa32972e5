"""WiFi fingerprinting: exact synthetic radio maps, bad scans, and the UJI month-1 files."""

from __future__ import annotations

import json

import numpy as np
import pytest

from evp.config import WifiSettings
from evp.errors import DatasetError
from evp.io.wifi_uji import read_database, read_set
from evp.wifi.evaluation import evaluate_methods
from evp.wifi.fingerprints import Fingerprints, averaged
from evp.wifi.knn import NOT_LOCATED_FLOOR, build_radio_map, locate
from evp.wifi.methods import PAPER, PLAIN, TUNED, compared_methods
from evp.wifi.tuning import tuned_k
from tests.cli.conftest import evp
from tests.conftest import shared

ACCESS_POINTS = np.array([[0.0, 0.0], [6.0, 0.0], [0.0, 5.0], [6.0, 5.0]])


def path_loss(positions: np.ndarray, floor_offset_db: float = 0.0) -> np.ndarray:
    """Log-distance path loss (seed 001's set-up): -40 dBm at 1 m, exponent 2.5."""
    distance = np.maximum(np.linalg.norm(positions[:, None] - ACCESS_POINTS[None], axis=2), 0.1)
    return -40.0 - 25.0 * np.log10(distance) + floor_offset_db


def grid_survey(samples_per_place: int = 3, noise_db: float = 0.0, seed: int = 0) -> Fingerprints:
    """A 1 m grid over 6 x 5 m on two floors (the upper one 15 dB weaker), ``samples_per_place`` each."""
    rng = np.random.default_rng(seed)
    xs, ys = np.meshgrid(np.arange(0.5, 6.0), np.arange(0.5, 5.0))
    places = np.column_stack([xs.ravel(), ys.ravel()])
    positions = np.repeat(np.vstack([places, places]), samples_per_place, axis=0)
    floors = np.repeat(np.r_[np.zeros(len(places), int), np.ones(len(places), int)], samples_per_place)
    rss = path_loss(positions) - 15.0 * floors[:, None] + rng.normal(0, noise_db, (len(positions), len(ACCESS_POINTS)))
    return Fingerprints(rss, positions, floors, ("a", "b", "c", "d"))


def test_weighted_knn_returns_the_surveyed_cell_of_an_exact_scan():
    survey = grid_survey()
    radio_map = build_radio_map(survey, PAPER, -105.0, 0.05)
    assert len(radio_map.fingerprints) == 60  # averaged: one fingerprint per grid node
    scans = np.vstack([path_loss(np.array([[2.5, 3.5]])), path_loss(np.array([[4.5, 0.5]])) - 15.0])
    found = locate(radio_map, scans, PAPER)
    np.testing.assert_allclose(found.positions, [[2.5, 3.5], [4.5, 0.5]], atol=1e-3)
    np.testing.assert_array_equal(found.floors, [0, 1])


def test_a_scan_between_nodes_lands_between_them():
    survey = grid_survey()
    found = locate(build_radio_map(survey, PAPER, -105.0, 0.05), path_loss(np.array([[3.0, 2.5]])), PAPER)
    assert np.linalg.norm(found.positions[0] - [3.0, 2.5]) < 0.5


def test_a_scan_with_no_known_access_point_is_not_located():
    survey = grid_survey()
    scans = np.array([[np.nan] * 4, path_loss(np.array([[1.5, 1.5]]))[0]])
    for method in (PLAIN, PAPER, TUNED):
        found = locate(build_radio_map(survey, method, -105.0, 0.05), scans, method)
        assert not found.located[0] and np.isnan(found.positions[0]).all() and found.floors[0] == NOT_LOCATED_FLOOR
        assert found.located[1] and np.linalg.norm(found.positions[1] - [1.5, 1.5]) < 1e-3
    test = Fingerprints(scans, np.array([[0.5, 0.5], [1.5, 1.5]]), np.array([0, 0]), survey.access_points)
    scores = evaluate_methods(survey, {"tst": test}, [PAPER], -105.0, 0.05)["methods"]["wknn_paper"]
    assert scores["per_set"]["tst"]["not_located"] == 1 and scores["mean_error_m"] < 1e-3 and scores["floor_accuracy"] == 1.0


def test_averaging_keeps_an_access_point_nobody_heard_unheard():
    rss = np.array([[-50.0, np.nan, np.nan], [-60.0, -70.0, np.nan]])
    places = averaged(Fingerprints(rss, np.zeros((2, 2)), np.zeros(2, int), ("a", "b", "c")), 0.05, -105.0)
    np.testing.assert_allclose(places.rss, [[-55.0, -87.5, np.nan]])


def test_k_is_chosen_by_cross_validation_inside_the_radio_map():
    survey = grid_survey(samples_per_place=4, noise_db=3.0)
    method, errors = tuned_k(survey, TUNED, [1, 4, 8], -105.0, 0.05)
    assert set(errors) == {1, 4, 8} and method.k == min(errors, key=errors.get)


def _write_set(folder, name: str, fingerprints: Fingerprints) -> None:
    np.savetxt(folder / f"{name}rss.csv", np.nan_to_num(fingerprints.rss, nan=100.0), fmt="%d", delimiter=",")
    np.savetxt(folder / f"{name}crd.csv", np.column_stack([fingerprints.positions, fingerprints.floors]), fmt="%.3f", delimiter=",")


def test_reader_rejects_an_impossible_rss_with_its_line(tmp_path):
    survey = grid_survey()
    _write_set(tmp_path, "trn01", survey)
    text = (tmp_path / "trn01rss.csv").read_text().splitlines()
    text[4] = "20" + text[4][text[4].index(",") :]
    (tmp_path / "trn01rss.csv").write_text("\n".join(text) + "\n")
    with pytest.raises(DatasetError, match="line 5"):
        read_set(tmp_path, "trn01")


def test_eval_and_locate_commands_on_a_uji_layout(tmp_path):
    database = tmp_path / "db01"
    database.mkdir()
    survey = grid_survey(samples_per_place=2, noise_db=2.0)
    _write_set(database, "trn01", survey)
    _write_set(database, "tst01", grid_survey(samples_per_place=1, noise_db=2.0, seed=1))
    config = tmp_path / "settings.yaml"
    config.write_text("wifi:\n  k_candidates: [1, 3]\n")
    result = evp("wifi", "eval", tmp_path, "--json", tmp_path / "wifi.json", "--config", config)
    assert result.returncode == 0, result.stderr
    assert result.stdout.startswith("knn3 ") and "choosing k" in result.stderr  # stdout holds results only, progress goes to stderr
    scores = json.loads((tmp_path / "wifi.json").read_text())["methods"]
    assert set(scores) == {"knn3", "wknn_paper", "wknn_cv"}
    assert set(scores["knn3"]) == {"mean_error_m", "floor_accuracy", "unseen_points_mean_error_m", "per_set"} and "tst01" in scores["knn3"]["per_set"]
    assert evp("wifi", "build", tmp_path, "--out", tmp_path / "map.npz").returncode == 0
    (tmp_path / "scans.csv").write_text("100,100,100,100\n" + ",".join(str(int(v)) for v in path_loss(np.array([[2.5, 1.5]]))[0]) + "\n")
    located = evp("wifi", "locate", tmp_path / "map.npz", tmp_path / "scans.csv", "--method", "wknn_paper")
    assert located.returncode == 0, located.stderr
    lines = [line for line in located.stdout.splitlines() if line]
    assert "not located" in lines[0] and lines[1].split()[3] == "0"
    misplaced = evp("wifi", "eval", database / "trn01rss.csv")
    assert misplaced.returncode == 3 and f"a file, and the folder holding the UJI sets is needed here: give {database}" in misplaced.stderr


def test_uji_month_one_knn3_and_the_stronger_method():
    """Month 1 of the UJI long-term library data: plain 3-NN as its README measured it, and the
    cross-validated W-KNN better on the points the survey never stood on."""
    survey, tests = read_database(shared("wifi_uji_library_month01"))
    assert len(survey) == 576 and set(tests) == {"tst01", "tst02", "tst03", "tst04", "tst05"}
    settings = WifiSettings(k_candidates=[3, 15])
    methods, _ = compared_methods(survey, settings)
    scores = evaluate_methods(survey, tests, methods, settings.not_detected_dbm, settings.place_tolerance_m)["methods"]
    for name in ("tst01", "tst02", "tst03", "tst04", "tst05"):
        assert 2.3 <= scores["knn3"]["per_set"][name]["mean_error_m"] <= 3.1
    assert scores["knn3"]["floor_accuracy"] >= 0.997
    assert scores["wknn_cv"]["unseen_points_mean_error_m"] < 0.9 * scores["knn3"]["unseen_points_mean_error_m"]
