"""One family of calibration files for every command: each format evp camera --to writes reads
back as the same camera, calib.txt (RPG numbers or KITTI's P0 line) takes the images' size, and
--camera FILE|PROFILE completes a dataset that has no calibration."""

from __future__ import annotations

import sys

import pytest

from evp.calib.camera_files import CAMERA_FILE_WRITERS, read_camera
from evp.calib.profiles import camera_from, load_profile
from evp.cli.app import main
from evp.config import Settings
from evp.errors import CalibrationError
from evp.io.registry import open_dataset
from evp.run_setup import camera_for, with_camera
from tests.io import builders

NEXUS = load_profile("nexus5x_640x380")
SUFFIX = {"yaml": ".yaml", "ros": ".yaml", "txt": ".txt"}


@pytest.mark.parametrize("fmt", sorted(CAMERA_FILE_WRITERS))
def test_every_written_format_reads_back(tmp_path, fmt):
    path = tmp_path / f"camera{SUFFIX[fmt]}"
    path.write_text(CAMERA_FILE_WRITERS[fmt](NEXUS))
    back = read_camera(path, NEXUS.width, NEXUS.height)
    for key in ("width", "height", "fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3"):
        assert getattr(back, key) == pytest.approx(getattr(NEXUS, key)), (fmt, key)


def test_calib_txt_cannot_hold_a_fisheye():
    from evp.sim.scenarios import fisheye_camera

    with pytest.raises(CalibrationError, match="--to yaml or --to ros"):
        CAMERA_FILE_WRITERS["txt"](fisheye_camera(640, 480, 150.0, (0.0,) * 4, "fisheye"))


def test_kitti_calib_txt_is_a_calibration_file(tmp_path):
    path = tmp_path / "calib.txt"
    path.write_text("P0: 718.856 0 607.1928 0 0 718.856 185.2157 0 0 0 1 0\nP1: 718.856 0 607.1928 -386.1448 0 718.856 185.2157 0 0 0 1 0\n")
    camera = camera_from(str(path), (1241, 376))
    assert (camera.width, camera.fx, camera.cy) == (1241, 718.856, 185.2157)
    with pytest.raises(CalibrationError, match="does not say the image size"):
        read_camera(path)


def test_a_calibration_is_scaled_to_the_images_of_its_shape_and_refused_for_another():
    half = camera_from("nexus5x_640x380", (320, 190))
    assert half.fx == pytest.approx(NEXUS.fx / 2)
    with pytest.raises(CalibrationError, match="another shape"):
        camera_from("nexus5x_640x380", (240, 180))


def test_camera_option_completes_a_folder_without_calibration(tmp_path, monkeypatch, capsys):
    root = builders.make_image_folder(tmp_path / "ds")
    calib = tmp_path / "my_calib.txt"
    (root / "calib.txt").rename(calib)
    camera = camera_for(open_dataset(root), with_camera(Settings(), str(calib)))
    assert (camera.width, camera.height, camera.fx) == (240, 180, pytest.approx(335.419))
    monkeypatch.setattr(sys, "argv", ["evp", "info", str(root), "--camera", str(calib)])
    with pytest.raises(SystemExit) as exited:
        main()
    assert exited.value.code in (0, None)
    assert "calibration: my_calib 240x180 fx 335.419" in capsys.readouterr().out
