"""The command line as a user meets it (run as a real subprocess where exit codes and stderr matter)."""

import json
import subprocess
import sys

import pytest
import yaml

from evp import __version__
from evp.io.trajectory import read_trajectory
from tests.conftest import SAMPLE


def evp(*args, cwd=None):
    return subprocess.run([sys.executable, "-m", "evp.cli", *map(str, args)], capture_output=True, text=True, cwd=cwd, timeout=300)


def test_version_and_help():
    assert evp("--version").stdout.strip() == f"evp {__version__}"
    out = evp("--help").stdout
    assert "Examples" in out and "evp eval" in out
    for command in ("info", "eval", "calibrate", "convert", "camera", "config", "formats"):
        assert command in out


def test_info_on_bundled_sample():
    result = evp("info", SAMPLE)
    assert result.returncode == 0, result.stderr
    assert "[image-folder]" in result.stdout and "camera frames: 87" in result.stdout
    data = json.loads(evp("info", SAMPLE, "--json").stdout)
    assert data["frames"] == 87 and data["calibration"]["width"] == 240
    assert data["ground_truth"]["path_length_m"] == pytest.approx(0.996, abs=0.01)


def test_errors_are_one_line_and_debug_shows_traceback(tmp_path):
    result = evp("info", tmp_path / "missing")
    assert result.returncode == 2
    assert result.stderr.strip().startswith("error:") and len(result.stderr.strip().splitlines()) == 1
    debug = evp("--debug", "info", tmp_path / "missing")
    assert debug.returncode != 0 and "Traceback" in debug.stderr


def test_eval_contract_json_and_report(tmp_path):
    gt = SAMPLE / "groundtruth.txt"
    truth = read_trajectory(gt)
    # a slightly noisy, scaled, shifted copy
    import numpy as np

    from evp.io.trajectory import write_trajectory
    from evp.types import Trajectory

    rng = np.random.default_rng(0)
    est = Trajectory(2.0 * truth.positions + [1, 2, 3] + rng.normal(0, 0.002, truth.positions.shape), truth.quats_xyzw, truth.timestamps)
    write_trajectory(tmp_path / "est.tum", est)
    result = evp("eval", gt, tmp_path / "est.tum", "--align", "sim3", "--json", tmp_path / "m.json", "--report", tmp_path / "report")
    assert result.returncode == 0, result.stderr
    metrics = json.loads((tmp_path / "m.json").read_text())
    for key in ("rmse", "mean", "median", "std", "min", "max", "q1", "q3", "iqr", "matched_poses"):
        assert key in metrics
    assert metrics["matched_poses"] == len(truth)
    assert metrics["rmse"] < 0.005
    assert metrics["options"]["align"] == "sim3"
    assert yaml.safe_load((tmp_path / "report" / "settings.yaml").read_text())["eval"]["align"] == "sim3"
    plots = ("top_view.png", "ape_over_time.png", "ape_histogram.png", "ape_boxplot.png")
    for name in plots:
        assert (tmp_path / "report" / name).stat().st_size > 1000
    # the summary's length moves with number formatting: check what it says, not its size
    report = (tmp_path / "report" / "report.md").read_text()
    assert f"matched poses: {len(truth)}" in report and "alignment: sim3" in report
    for statistic in ("rmse", "median", "iqr"):
        assert f"| {statistic} |" in report
    for name in plots:
        assert f"]({name})" in report
    none = json.loads((evp("eval", gt, tmp_path / "est.tum", "--align", "none", "--json", tmp_path / "n.json"), (tmp_path / "n.json").read_text())[1])
    assert none["rmse"] > 1.0
    bad = evp("eval", gt, tmp_path / "est.tum", "--align", "affine")
    assert bad.returncode == 2 and "align" in bad.stderr


def test_eval_n_align_and_kitti_times(tmp_path):
    (tmp_path / "gt.txt").write_text("".join(f"1 0 0 {i} 0 1 0 {0.1 * i * i} 0 0 1 0\n" for i in range(10)))
    (tmp_path / "est.txt").write_text("".join(f"1 0 0 {i * 1.1} 0 1 0 {0.1 * i * i} 0 0 1 0\n" for i in range(10)))
    (tmp_path / "times.txt").write_text("".join(f"{i * 0.1}\n" for i in range(10)))
    result = evp("eval", tmp_path / "gt.txt", tmp_path / "est.txt", "--align", "se3", "--n-align", "3", "--json", tmp_path / "m.json")
    assert result.returncode == 0, result.stderr
    assert json.loads((tmp_path / "m.json").read_text())["max"] > 0.5
    tum = evp("convert", tmp_path / "gt.txt", tmp_path / "gt.tum", "--to", "tum", "--times", tmp_path / "times.txt")
    assert tum.returncode == 0, tum.stderr
    mixed = evp("eval", tmp_path / "gt.tum", tmp_path / "est.txt")
    assert mixed.returncode == 2 and "--est-times" in mixed.stderr
    ok = evp("eval", tmp_path / "gt.tum", tmp_path / "est.txt", "--est-times", tmp_path / "times.txt", "--align", "sim3")
    assert ok.returncode == 0, ok.stderr


def test_config_dump_is_valid_yaml():
    result = evp("config", "dump")
    assert result.returncode == 0
    assert yaml.safe_load(result.stdout)["orb"]["n_features"] == 1000


def test_camera_profile_and_formats():
    result = evp("camera", "nexus5x_640x380")
    assert "fx 494.0800" in result.stdout
    assert "nexus5x_640x380" in evp("camera", "list").stdout
    assert "exif-photos" in evp("formats").stdout


def test_calibrate_command_writes_opencv_yaml(tmp_path):
    import cv2

    from evp.calib.camera_files import load_yaml_mapping, read_camera
    from evp.calib.profiles import load_profile
    from evp.sim.calibration_target import chessboard_texture, random_board_poses, render_board

    camera = load_profile("nexus5x_640x380")
    texture, origin = chessboard_texture(9, 7)
    for i, (r, t) in enumerate(random_board_poses(camera, 8, 9, 7, 0.03, seed=7, origin_offset_m=0.03)):
        cv2.imwrite(str(tmp_path / f"{i:02d}.png"), render_board(camera, texture, origin, 0.03, r, t))
    out = tmp_path / "out" / "camera.yaml"
    result = evp("calibrate", tmp_path, "--cols", 9, "--rows", 7, "--square", 0.03, "--out", out)
    assert result.returncode == 0, result.stderr
    assert "RMS reprojection error" in result.stdout
    assert read_camera(out).fx == pytest.approx(494.08, rel=0.005)
    stored = load_yaml_mapping(out)
    assert stored["board_square_m"] == pytest.approx(0.03) and stored["board_pattern"] == "chessboard" and stored["views_used"] == 8
    empty = tmp_path / "empty"
    empty.mkdir()
    failed = evp("calibrate", empty, "--cols", 9, "--rows", 7, "--square", 0.03)
    assert failed.returncode == 2 and "no images" in failed.stderr
