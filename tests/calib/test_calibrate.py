"""Calibration recovers known intrinsics from exactly rendered board views."""

import cv2
import numpy as np
import pytest

from evp.calib.calibrate import BoardSpec, calibrate_views, images_from_path
from evp.calib.profiles import load_profile
from evp.errors import CalibrationError, UsageError
from evp.sim.calibration_target import charuco_texture, chessboard_texture, random_board_poses, render_board

NEXUS = load_profile("nexus5x_640x380")
SQUARE = 0.03


def _chessboard_views(camera, count, seed):
    texture, origin = chessboard_texture(9, 7)
    poses = random_board_poses(camera, count, 9, 7, SQUARE, seed=seed, origin_offset_m=SQUARE)
    return [(f"view_{i:02d}.png", render_board(camera, texture, origin, SQUARE, r, t)) for i, (r, t) in enumerate(poses)]


def _relative_errors(found, truth):
    return {k: abs(getattr(found, k) - getattr(truth, k)) / getattr(truth, k) for k in ("fx", "fy", "cx", "cy")}


def test_chessboard_recovers_nexus_intrinsics_within_half_a_percent():
    result = calibrate_views(_chessboard_views(NEXUS, 12, seed=1), BoardSpec("chessboard", 9, 7, SQUARE))
    errors = _relative_errors(result.camera, NEXUS)
    assert max(errors.values()) < 0.005, errors
    assert result.camera.k1 == pytest.approx(NEXUS.k1, abs=0.01)
    assert result.camera.p1 == pytest.approx(NEXUS.p1, abs=0.002)
    assert result.rms_px < 0.2
    assert not result.rejected


def test_charuco_recovers_intrinsics_within_half_a_percent():
    board = BoardSpec("charuco", 9, 7, SQUARE, 0.022)
    texture, origin = charuco_texture(board.charuco_board())
    poses = random_board_poses(NEXUS, 12, 9, 7, SQUARE, seed=2)
    views = [(f"v{i}", render_board(NEXUS, texture, origin, SQUARE, r, t)) for i, (r, t) in enumerate(poses)]
    result = calibrate_views(views, board)
    assert max(_relative_errors(result.camera, NEXUS).values()) < 0.005


def test_bad_views_are_rejected_and_reported():
    views = _chessboard_views(NEXUS, 10, seed=3)
    blank = np.full((NEXUS.height, NEXUS.width), 255, np.uint8)
    # a view with a wrongly ordered detection: flip the image, the corners no longer fit the camera model
    name, image = views[4]
    warped = cv2.warpAffine(image, np.array([[1.0, 0.08, 0.0], [0.04, 1.0, -8.0]]), (NEXUS.width, NEXUS.height), borderValue=255)
    views[4] = (name, warped)
    views.append(("blank.png", blank))
    result = calibrate_views(views, BoardSpec("chessboard", 9, 7, SQUARE))
    assert result.rejected["blank.png"] == "board not found"
    assert name in result.rejected and "reprojection error" in result.rejected[name]
    assert max(_relative_errors(result.camera, NEXUS).values()) < 0.005
    assert "rejected blank.png" in result.report()


def test_too_few_views_is_a_clear_error():
    views = _chessboard_views(NEXUS, 2, seed=4)
    with pytest.raises(CalibrationError, match="found in 2 of 2 images"):
        calibrate_views(views, BoardSpec("chessboard", 9, 7, SQUARE))


def test_board_given_as_inner_corners_gets_the_right_options_named():
    """--cols 8 --rows 6 (the inner corners of a 9x7 board): the error names the source, no
    placeholder, and the options that find the board."""
    views = _chessboard_views(NEXUS, 2, seed=4)
    with pytest.raises(CalibrationError) as caught:
        calibrate_views(views, BoardSpec("chessboard", 8, 6, SQUARE), source="board/")
    message = str(caught.value)
    assert message.startswith("board: the board was found in 0 of 2 images")
    assert "--cols 9 --rows 7" in message and "<" not in message


def test_board_spec_validation():
    with pytest.raises(UsageError):
        BoardSpec("circles", 9, 7, 0.03)
    with pytest.raises(UsageError):
        BoardSpec("charuco", 9, 7, 0.03, 0.04)


def test_images_from_folder_and_video(tmp_path):
    views = _chessboard_views(NEXUS, 3, seed=5)
    for name, image in views:
        cv2.imwrite(str(tmp_path / name), image)
    assert [n for n, _ in images_from_path(tmp_path)] == [n for n, _ in views]
    writer = cv2.VideoWriter(str(tmp_path / "board.avi"), cv2.VideoWriter_fourcc(*"MJPG"), 5, (NEXUS.width, NEXUS.height))
    for _, image in views:
        writer.write(cv2.cvtColor(image, cv2.COLOR_GRAY2BGR))
    writer.release()
    assert len(list(images_from_path(tmp_path / "board.avi", every=2))) == 2
    with pytest.raises(CalibrationError):
        list(images_from_path(tmp_path / "missing.avi"))
