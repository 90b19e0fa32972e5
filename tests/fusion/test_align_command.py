"""`evp align` end to end: the JSON contract on a simulated flight, the real survey photos, and
surveys too short to hold validation pairs out."""

import json
import shutil
import subprocess
import sys

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from evp.io.registry import open_dataset
from evp.io.trajectory import read_trajectory, write_trajectory
from evp.sim.generate import generate
from evp.sim.scenarios import SimOptions
from evp.sim.sensors import GpsConfig
from evp.types import Trajectory
from tests.conftest import shared
from tests.io.builders import write_geotagged_jpeg

CONTRACT = ("mean", "max", "rmse", "q1", "q3", "iqr", "std", "n_evaluated")


def evp(*args):
    return subprocess.run([sys.executable, "-m", "evp.cli", *map(str, args)], capture_output=True, text=True, timeout=900)


@pytest.fixture(scope="module")
def spoofed_flight(tmp_path_factory):
    """A 160 s survey at 40 m, GPS pulled off at 5 m/s from t = 120 s, images at 2 fps (cheap)."""
    root = tmp_path_factory.mktemp("flight")
    options = SimOptions(duration_s=160.0, fps=2.0, relief=False, altitude_m=40.0, gps=GpsConfig(spoof_start_s=120.0, spoof_rate_m_s=5.0, clock_offset_s=0.3))
    generate("drone-flight", options, root / "data", workers=1)
    truth = read_trajectory(root / "data" / "groundtruth_cam0_tum.txt")
    rng = np.random.default_rng(0)
    # a visual track in its own frame and scale, drifting slowly, as an estimator would give
    drift = np.cumsum(rng.normal(0, 0.02, truth.positions.shape), axis=0)
    odometry = Trajectory((truth.positions + drift) * 0.1 + [5.0, -2.0, 1.0], truth.quats_xyzw, truth.timestamps)
    write_trajectory(root / "odometry.tum", odometry)
    return root


def test_align_json_contract_and_spoofing_event(spoofed_flight, tmp_path):
    out = tmp_path / "aligned"
    result = evp(
        "align", spoofed_flight / "data", "--trajectory", spoofed_flight / "odometry.tum", "--align-fraction", 0.4, "--json", tmp_path / "m.json", "--out", out
    )
    assert result.returncode == 0, result.stderr
    metrics = json.loads((tmp_path / "m.json").read_text())
    for key in CONTRACT:
        assert key in metrics
    assert metrics["n_evaluated"] > 500
    assert metrics["alignment"]["clock_offset_s"] == pytest.approx(0.3, abs=0.1)
    assert [e["kind"] for e in metrics["events"]][:1] == ["spoofing_alarm"]
    alarm = metrics["events"][0]["t"] - 1_700_000_000 - 0.3
    assert 120.0 <= alarm <= 125.0
    for name in (
        "aligned_enu.tum",
        "aligned.csv",
        "aligned.geojson",
        "error_histogram.png",
        "error_boxplot.png",
        "trajectory_gps.png",
        "gps_trust.csv",
        "settings.yaml",
    ):
        assert (out / name).is_file(), name
    geojson = json.loads((out / "aligned.geojson").read_text())
    lon, lat, _ = geojson["features"][0]["geometry"]["coordinates"][0]
    assert lat == pytest.approx(43.7238, abs=0.01) and lon == pytest.approx(10.3966, abs=0.01)


def test_align_before_the_spoof_is_accurate(spoofed_flight, tmp_path):
    """Errors against GPS before the spoofing starts: metre level (GPS noise + drift)."""
    result = evp("align", spoofed_flight / "data", "--trajectory", spoofed_flight / "odometry.tum", "--mode", "2d+baro", "--json", tmp_path / "m.json")
    assert result.returncode == 0, result.stderr
    metrics = json.loads((tmp_path / "m.json").read_text())
    assert metrics["alignment"]["mode"] == "2d+baro"
    assert metrics["q1"] < 3.0  # most fixes (before the pull-off) agree to metres


def test_align_without_gps_is_a_clear_error(tmp_path, sample_path):
    result = evp("align", sample_path, "--json", tmp_path / "m.json")
    assert result.returncode == 3 and "no GPS" in result.stderr  # bad input data
    bad_mode = evp("align", sample_path, "--mode", "4d+baro")
    assert bad_mode.returncode == 2 and "--mode must be" in bad_mode.stderr


def test_real_survey_photos_align_on_the_first_third(tmp_path):
    photos = shared("aerial_nadir_odm_toledo_fc350")
    # the live poses keep this test cheap; the refined track (the default) is bench/'s to measure
    result = evp("align", photos, "--align-fraction", 0.333, "--json", tmp_path / "m.json", "--track", "live")
    assert result.returncode == 0, result.stderr
    assert "visual track: the nadir estimator's live poses" in result.stdout
    metrics = json.loads((tmp_path / "m.json").read_text())
    assert metrics["n_evaluated"] >= 30
    # the survey spans 150 x 180 m; a working pipeline stays within tens of metres of GPS at worst
    assert metrics["mean"] < 20.0 and metrics["max"] < 60.0


def _align_short_survey(photos, tmp_path):
    """evp align on a short photo survey, with its GPS track in another frame and scale as the
    visual track, aligned on half of the fixes."""
    gps = open_dataset(photos).ground_truth
    R = Rotation.from_euler("z", 40, degrees=True).as_matrix()
    write_trajectory(tmp_path / "visual.tum", Trajectory(gps.positions @ R * 0.1, gps.quats_xyzw, gps.timestamps))
    result = evp("align", photos, "--trajectory", tmp_path / "visual.tum", "--align-fraction", 0.5, "--json", tmp_path / "m.json", "--out", tmp_path / "out")
    assert result.returncode == 0, result.stderr
    assert "not validated: too few pairs to hold some out" in result.stdout
    assert f"visual track: the trajectory file {tmp_path / 'visual.tum'}" in result.stdout
    assert "too few to hold 3 out for validation: fitted on all of them with the default settings" in result.stderr
    metrics = json.loads((tmp_path / "m.json").read_text())
    assert metrics["alignment"]["validation_rmse_m"] is None and metrics["alignment"]["model"] == "similarity"
    assert any("not validated" in w for w in json.loads((tmp_path / "out" / "metrics.json").read_text())["warnings"])
    return metrics


def test_a_ten_photo_survey_aligns_on_all_its_pairs(tmp_path):
    photos = tmp_path / "photos"
    photos.mkdir()
    for i in range(10):  # two flight lines, 5 s apart: 25 m north-south legs, 20 m between them
        lat, lon = 41.5486 + (i % 5 if i < 5 else 9 - i) * 5e-5, -83.6986 + (i // 5) * 2.4e-4
        write_geotagged_jpeg(photos / f"IMG_{i:04d}.jpg", 5 * i, lat, lon, 120.0 + i % 3)
    metrics = _align_short_survey(photos, tmp_path)
    assert metrics["n_evaluated"] == 4 and metrics["max"] < 0.5  # GPS stored to 1e-4 arc-seconds, altitude to 0.1 m


def test_ten_real_survey_photos_align_on_all_their_pairs(tmp_path):
    survey = shared("aerial_nadir_odm_toledo_fc350")
    photos = tmp_path / "photos"
    photos.mkdir()
    for photo in sorted((survey / "images").glob("*.jpg"))[:10]:
        shutil.copy(photo, photos / photo.name)
    metrics = _align_short_survey(photos, tmp_path)
    assert metrics["n_evaluated"] >= 3 and metrics["max"] < 1.0
