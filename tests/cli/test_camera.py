"""evp calibrate and evp camera."""

import pytest

from evp.errors import ExitCode
from tests.cli.conftest import evp


def test_camera_profile():
    result = evp("camera", "nexus5x_640x380")
    assert "fx 494.0800" in result.stdout
    assert "nexus5x_640x380" in evp("camera", "list").stdout


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
    assert failed.returncode == ExitCode.DATA and "no images" in failed.stderr


def test_calibrate_bad_board_is_a_usage_error(tmp_path):
    result = evp("calibrate", tmp_path, "--pattern", "circles", "--cols", 9, "--rows", 7, "--square", 0.03)
    assert result.returncode == ExitCode.USAGE and "unknown board kind" in result.stderr


def test_camera_rescale_to_a_bad_size_is_a_usage_error():
    result = evp("camera", "nexus5x_640x380", "--width", -5, "--height", 10)
    assert result.returncode == ExitCode.USAGE and "--width" in result.stderr
