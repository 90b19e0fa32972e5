"""``evp run --estimator ekf-slam`` on a short render of seed 001's robot room, and the datasets
it cannot run on."""

from __future__ import annotations

import json

from tests.cli.conftest import evp
from tests.conftest import SAMPLE


def test_evp_run_ekf_slam_on_the_rendered_robot_room(tmp_path):
    data, out = tmp_path / "robot", tmp_path / "run"
    rendered = evp("sim", "wheel-robot-room", "--out", data, "--duration", "4", "--fps", "8", "--seed", "4", "--workers", "1")
    assert rendered.returncode == 0, rendered.stderr
    result = evp("run", data, "--estimator", "ekf-slam", "--out", out)
    assert result.returncode == 0, result.stderr
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["tracked_frames"] == metrics["frames"]
    assert metrics["rmse"] < 0.02  # metric, rigidly aligned (no scale)
    assert "align: se3" in (out / "settings.yaml").read_text()
    assert metrics["ekf_slam"]["features_max"] <= 100 and metrics["ekf_slam"]["matched_per_frame_median"] >= 10
    assert (out / "trajectory.tum").read_text().count("\n") == metrics["frames"] + 1  # and the header


def test_ekf_slam_refuses_a_dataset_without_wheels(tmp_path):
    result = evp("run", SAMPLE, "--estimator", "ekf-slam", "--out", tmp_path / "run")
    assert result.returncode in (2, 3) and "ekf-slam needs" in result.stderr


def test_an_unknown_estimator_is_a_usage_error(tmp_path):
    result = evp("run", SAMPLE, "--estimator", "ekf_slam", "--out", tmp_path / "run")
    assert result.returncode == 2 and "choose one of" in result.stderr
