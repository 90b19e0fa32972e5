"""evp info, evp run, evp formats."""

import json

import numpy as np
import pytest
import yaml

from evp.io.registry import open_dataset
from tests.cli.conftest import evp
from tests.conftest import SAMPLE
from tests.io import builders


def test_info_on_bundled_sample():
    result = evp("info", SAMPLE)
    assert result.returncode == 0, result.stderr
    assert "[image-folder]" in result.stdout and "camera frames: 87" in result.stdout
    data = json.loads(evp("info", SAMPLE, "--json").stdout)
    assert data["frames"] == 87 and data["calibration"]["width"] == 240
    assert data["ground_truth"]["path_length_m"] == pytest.approx(0.996, abs=0.01)


def test_formats():
    assert "exif-photos" in evp("formats").stdout


def test_run_writes_the_settings_that_ran(tmp_path):
    """settings.yaml names the estimator auto chose and the time tolerance the evaluation used,
    which is half the sample's median frame period, as metrics.json says."""
    result = evp("run", SAMPLE, "--out", tmp_path)
    assert result.returncode == 0, result.stderr
    assert "ATE (Sim3-aligned RMSE)" in result.stdout
    assert "dropped" not in result.stdout  # every frame is fed unless --realtime
    written = yaml.safe_load((tmp_path / "settings.yaml").read_text())
    assert written["estimator"] == "slam"
    half_period = float(0.5 * np.median(np.diff(open_dataset(SAMPLE).frame_times)))
    assert written["eval"]["max_time_diff_s"] == half_period
    metrics = json.loads((tmp_path / "metrics.json").read_text())
    assert metrics["options"]["max_diff_s"] == half_period and metrics["options"]["align"] == written["eval"]["align"] == "sim3"
    # every tracked pose has ground truth, except the SLAM initialisation reference when that is
    # frame 0: the sample's ground truth starts 22 ms after it (more than half a frame period)
    assert metrics["matched_poses"] >= metrics["tracked_frames"] - 1


@pytest.mark.parametrize("count", [1, 2])
def test_run_on_a_sequence_too_short_to_initialise_ends_with_one_line(tmp_path, count):
    root = builders.make_image_folder(tmp_path / "short", count=count)
    result = evp("run", root, "--out", tmp_path / "out")
    assert result.returncode == 3  # bad input data
    # off a terminal the progress lines come first (tests/cli/test_progress.py), then one error line
    lines = [line for line in result.stderr.strip().splitlines() if line.startswith("error:")]
    assert len(lines) == 1 and "too short or too still to initialise: no frame tracked" in lines[0], result.stderr
    assert "the camera must move sideways" in lines[0]
    assert f"in {count} frame" in lines[0] and "Traceback" not in result.stderr


def test_info_prints_the_readers_warnings(tmp_path):
    root = builders.make_kitti(tmp_path / "kitti")
    (root / "times.txt").unlink()
    result = evp("info", root)
    assert result.returncode == 0, result.stderr
    assert "[kitti]" in result.stdout and "warning: no times.txt: frames stamped at KITTI's nominal 10 Hz" in result.stdout
