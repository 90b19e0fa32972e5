"""Ground-vehicle recordings without a camera: the CMU plaza and TU Chemnitz labyrinth readers on
the real folders and on damaged copies, and comma2k19's ENU origin."""

import math
import shutil

import numpy as np
import pytest

from evp.errors import DatasetError
from evp.io.registry import detect_reader, open_dataset
from evp.io.summary import describe, summarise
from tests.conftest import shared

PLAZA = "cmu_plaza1_wheel_odometry"
LABYRINTH = "tuc_labyrinth_wheel_odometry"


def test_plaza1_counts_durations_and_increments():
    path = shared(PLAZA)
    assert detect_reader(path).name == "cmu-plaza"
    dataset = open_dataset(path)
    assert len(dataset.wheel) == 9657 and len(dataset.beacon_ranges) == 3529 and len(dataset.ground_truth) == 9658
    assert set(dataset.beacons) == {"0", "1", "5", "6"} and dataset.beacons["0"] == pytest.approx((-46.623234, 11.025549, 0.0))
    assert dataset.ground_truth.duration == pytest.approx(1933.44, abs=0.01)
    assert dataset.ground_truth.path_length == pytest.approx(1859.0, abs=0.5)
    # speeds x intervals give the increments back: the path the odometry drove (README: ~1861 m)
    stamps = np.array([dataset.ground_truth.timestamps[0], *[w.timestamp for w in dataset.wheel]])
    driven = sum(w.forward_speed_m_s * dt for w, dt in zip(dataset.wheel, np.diff(stamps)))
    assert driven == pytest.approx(1861, abs=3)
    ranges = [r.timestamp for r in dataset.beacon_ranges]
    assert ranges == sorted(ranges) and any("not in time order" in w for w in dataset.warnings)
    assert dataset.sensors() == {"wheel": 9657, "beacon": 3529}
    assert "beacon 0: at" in describe(summarise(dataset))


def test_labyrinth_counts_and_wheel_model():
    path = shared(LABYRINTH)
    assert detect_reader(path).name == "tuc-labyrinth"
    dataset = open_dataset(path)
    assert len(dataset.wheel) == len(dataset.beacon_ranges) == len(dataset.ground_truth) == 233
    assert dataset.beacons["107"] == (-0.02, 2.365, 0.0) and len(dataset.beacons) == 4
    assert dataset.ground_truth.duration == pytest.approx(29.77, abs=0.01) and dataset.warnings == []
    moving = next(w for w in dataset.wheel if w.wheel_speeds_m_s[0] != w.wheel_speeds_m_s[1])
    left, right = moving.wheel_speeds_m_s
    assert moving.yaw_rate_rad_s == pytest.approx((left - right) / (2 * 0.0785))
    assert moving.forward_speed_m_s == pytest.approx((left + right) / 2)
    merged = list(dataset.telemetry())
    assert len(merged) == 466 and [r.timestamp for r in merged] == sorted(r.timestamp for r in merged)


def test_comma2k19_enu_origin_is_the_first_truth_position():
    dataset = open_dataset(shared("comma2k19_example_segment_sensors"))
    latitude, longitude, _ = dataset.enu_origin
    assert latitude == pytest.approx(37.7210, abs=1e-4) and longitude == pytest.approx(-122.4723, abs=1e-4)  # README


def _copy(tmp_path, folder):
    target = tmp_path / folder
    shutil.copytree(shared(folder), target)
    for path in target.iterdir():
        path.chmod(0o644)
    return target


def _append_rows(path, *rows):
    path.write_text(path.read_text() + "".join(f"{row}\n" for row in rows))


def test_bad_plaza_ranges_are_dropped_with_warnings_and_nothing_else_lost(tmp_path):
    path = _copy(tmp_path, PLAZA)
    ranges = path / "plaza1_ranges_TD.csv"
    lines = len(ranges.read_text().splitlines())
    _append_rows(ranges, "5791.0,2,9,12.5", "5792.0,2,0,nan", "5793.0,2,1,30.0", "10.0,2,5,40.0")
    dataset = open_dataset(path)
    assert len(dataset.beacon_ranges) == 3529 + 2  # the good late row and the early one kept
    assert dataset.beacon_ranges[0].timestamp == 10.0
    assert any(f"beacons not in the beacon list (9) dropped, first at line {lines + 1}" in w for w in dataset.warnings)
    assert any(f"not finite positive numbers dropped, first at line {lines + 2}" in w for w in dataset.warnings)
    assert all(math.isfinite(r.range_m) for r in dataset.beacon_ranges)


def test_plaza_odometry_going_back_in_time_is_an_error_naming_the_line(tmp_path):
    path = _copy(tmp_path, PLAZA)
    _append_rows(path / "plaza1_odometry_DR.csv", "5000.0,0.1,0.0")
    with pytest.raises(DatasetError, match=r"plaza1_odometry_DR.csv, line 9659: odometry timestamps must increase"):
        open_dataset(path)


def test_labyrinth_anchor_moving_between_rows_is_an_error(tmp_path):
    path = _copy(tmp_path, LABYRINTH)
    _append_rows(path / "uwb_ranges.csv", "30.0,1.0,0.01,5.0,5.0,105,0")
    with pytest.raises(DatasetError, match="uwb_ranges.csv, line 235: anchor 105 at"):
        open_dataset(path)
