"""The mistakes a new user makes in the first hour, each answered by one specific line (no
traceback), with the exit code of its category, before any long work starts.

The commands run in-process (``evp.cli.app.main`` with its argv), so the whole table costs
seconds; tests/cli/test_app.py checks the same entry point as a real subprocess.
"""

from __future__ import annotations

import shutil
import socket
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

from evp.cli.app import main
from evp.errors import ExitCode
from evp.io.trajectory import read_trajectory
from tests.conftest import SAMPLE


def evp_main(monkeypatch, capsys, *args) -> tuple[int, str]:
    """(exit code, stderr) of ``evp ARGS`` run in this process."""
    monkeypatch.setattr(sys, "argv", ["evp", *map(str, args)])
    with pytest.raises(SystemExit) as exited:
        main()
    return exited.value.code or 0, capsys.readouterr().err


def one_line_error(err: str) -> str:
    lines = [line for line in err.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("error: "), err
    assert "Traceback" not in err
    return lines[0]


@pytest.fixture
def a_file(tmp_path) -> Path:
    path = tmp_path / "results.txt"
    path.write_text("not a folder")
    return path


@pytest.fixture
def image_folder(tmp_path) -> Path:
    folder = tmp_path / "photos"
    folder.mkdir()
    for i in range(3):
        cv2.imwrite(str(folder / f"{i:03d}.png"), np.zeros((24, 32), np.uint8))
    return folder


GT = SAMPLE / "groundtruth.txt"


@pytest.mark.parametrize(
    ("args", "expected"),
    [
        (("run", SAMPLE, "--out", "{file}"), "--out {file}: is a file, and a folder is needed"),
        (("run", SAMPLE, "--out", "{file}/run"), "is a file, so nothing can be made under it"),
        (("sim", "drone-flight", "--out", "{file}", "--duration", "1"), "--out {file}: is a file"),
        (("eval", GT, GT, "--report", "{file}"), "--report {file}: is a file"),
        (("eval", GT, GT, "--json", "{tmp}"), "--json {tmp}: is a folder, and a file name is needed here, e.g."),
        (("calibrate", "{images}", "--cols", "9", "--rows", "7", "--square", "0.02", "--out", "{file}/camera.yaml"), "is a file, so nothing"),
        (("align", SAMPLE, "--out", "{file}"), "--out {file}: is a file"),
        (("align", SAMPLE, "--align-fraction", "1.5"), "--align-fraction 1.5: give a fraction between 0 and 1"),
        (("sweep", SAMPLE, "--set", "orb.n_features=500", "--out", "{file}"), "--out {file}: is a file"),
        (("convert", GT, "{tmp}"), "DST {tmp}: is a folder"),
    ],
)
def test_unusable_outputs_are_refused_before_the_work(monkeypatch, capsys, tmp_path, a_file, image_folder, args, expected):
    names = {"file": a_file, "tmp": tmp_path, "images": image_folder}
    code, err = evp_main(monkeypatch, capsys, *(str(a).format(**names) for a in args))
    assert code == ExitCode.USAGE
    assert expected.format(**names) in one_line_error(err)


def test_datasets_that_are_near_misses_say_what_is_missing(monkeypatch, capsys, tmp_path, image_folder):
    empty = tmp_path / "empty"
    empty.mkdir()
    others = tmp_path / "notes"
    others.mkdir()
    (others / "a.csv").write_text("x\n")
    (others / "b.txt").write_text("y\n")
    expected = {
        empty: "the folder is empty",
        image_folder: "a folder of 3 images needs their times: times.txt",
        others: "no images, video or recording here (its 2 files end .csv, .txt)",
    }
    tagged = tmp_path / "tags"  # apriltag_real_images: images/ beside a table with a header row
    shutil.copytree(image_folder, tagged / "images")
    (tagged / "rotation_reference.csv").write_text("file,ref_tag_yaw_deg\n000.png,0\n")
    expected[tagged] = "a folder of 3 images needs their times"
    expected[GT] = "no camera frames to run on: only trajectories here; compare two with evp eval REF EST"
    for path, message in expected.items():
        code, err = evp_main(monkeypatch, capsys, "run", path, "--out", tmp_path / "out")
        assert code == ExitCode.DATA
        assert message in one_line_error(err)
    assert "--camera FILE|PROFILE" in evp_main(monkeypatch, capsys, "info", image_folder)[1]


def test_a_recording_without_images_says_what_it_holds_and_what_runs_it(tmp_path):
    from evp.io.dataset import CAMERALESS_BENCH, Dataset
    from evp.types import WheelOdometry

    robot = Dataset("labyrinth", "tuc-labyrinth", tmp_path, wheel=[WheelOdometry(0.0, (0.1, 0.1))], ground_truth=read_trajectory(GT))
    reason = robot.no_frames_reason()
    assert "this tuc-labyrinth recording holds wheel odometry and ground truth" in reason and CAMERALESS_BENCH in reason
    assert (Path(__file__).parents[2] / CAMERALESS_BENCH.split()[-1]).is_file()


def test_a_misspelt_format_names_the_nearest(monkeypatch, capsys):
    code, err = evp_main(monkeypatch, capsys, "info", SAMPLE, "--format", "kitty")
    assert code == ExitCode.USAGE and "--format 'kitty': no such dataset format; did you mean kitti?" in one_line_error(err)


def test_settings_typo_names_the_nearest_key(monkeypatch, capsys, tmp_path):
    settings = tmp_path / "settings.yaml"
    settings.write_text("orb:\n  n_featurs: 500\n")
    code, err = evp_main(monkeypatch, capsys, "run", SAMPLE, "--out", tmp_path / "out", "--config", settings)
    assert code == ExitCode.USAGE
    assert one_line_error(err).endswith("orb.n_featurs: no such setting; did you mean orb.n_features?")
    settings.write_text("estimatr: slam\n")
    assert one_line_error(evp_main(monkeypatch, capsys, "config", "dump", settings)[1]).endswith("did you mean estimator?")


def test_camera_profile_names_are_one_list(monkeypatch, capsys, tmp_path):
    """evp sim takes the names evp camera lists; a near miss is named."""
    from evp.calib.profiles import profile_names
    from evp.sim.scenarios import SimOptions, build_scenario

    for name in profile_names():
        assert build_scenario("drone-flight", SimOptions(camera=name, duration_s=0.2)).camera.width > 0
    code, err = evp_main(monkeypatch, capsys, "sim", "drone-flight", "--camera", "global_shuter_752x480", "--out", tmp_path / "sim", "--duration", "0.2")
    assert code == ExitCode.USAGE
    assert "did you mean global_shutter_752x480?" in one_line_error(err)


def test_serve_on_a_busy_port_fails_before_its_banner_or_certificate(monkeypatch, capsys, tmp_path):
    pytest.importorskip("uvicorn")
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        port = busy.getsockname()[1]
        code, err = evp_main(monkeypatch, capsys, "serve", "--host", "127.0.0.1", "--port", port, "--data", tmp_path / "station")
    assert code == ExitCode.USAGE
    assert f"--port {port}: is in use" in one_line_error(err)
    assert not (tmp_path / "station").exists()
    assert capsys.readouterr().out == ""


@pytest.mark.parametrize(
    ("option", "expected"),
    [
        (("--cafile", "{tmp}/cert.pem"), "--cafile {tmp}/cert.pem: no such file; copy the station's <data>/tls/cert.pem"),
        (("--fingerprint", "AB:CD"), "--fingerprint AB:CD: expected the SHA-256 fingerprint as the operator page shows it"),
    ],
)
def test_stream_trust_options_are_checked_before_connecting(monkeypatch, capsys, tmp_path, option, expected):
    """A missing cert.pem was a traceback (websockets' lazily loaded exceptions module); a
    mangled fingerprint was blamed on the link."""
    pytest.importorskip("websockets")
    args = [a.format(tmp=tmp_path) for a in option]
    code, err = evp_main(monkeypatch, capsys, "stream", SAMPLE, "--url", "wss://127.0.0.1:9", *args)
    assert code == ExitCode.USAGE
    assert expected.format(tmp=tmp_path) in one_line_error(err)


def test_stream_with_an_unreadable_certificate_is_one_line(monkeypatch, capsys, tmp_path):
    pytest.importorskip("websockets")
    (tmp_path / "cert.pem").write_text("")  # failed in the TLS setup, before websockets had loaded its exceptions
    code, err = evp_main(monkeypatch, capsys, "stream", SAMPLE, "--url", "wss://127.0.0.1:9", "--cafile", tmp_path / "cert.pem")
    assert code == ExitCode.LINK
    assert "cannot connect to wss://127.0.0.1:9" in one_line_error(err)


def test_a_standing_camera_is_told_from_its_ground_truth(tmp_path):
    """EuRoC V1_01's first 1.45 s: the MAV on the ground, 2 mm of ground-truth motion, nothing tracked."""
    from evp.io.dataset import Dataset
    from evp.types import Trajectory

    times = np.arange(30) / 20.0
    positions = np.zeros((40, 3))
    positions[20:, 2] = 0.002  # settles by 2 mm while the frames run, then flies off after them
    positions[35:, 0] = 5.0
    standing = Trajectory(positions, np.tile([0.0, 0.0, 0.0, 1.0], (40, 1)), np.arange(40) / 20.0)
    dataset = Dataset("still", "euroc", tmp_path, None, times, ground_truth=standing)
    assert dataset.ground_truth_excursion() == pytest.approx(0.002)
    assert Dataset("no truth", "video", tmp_path, None, times).ground_truth_excursion() is None


def test_info_on_kitti_poses_without_times_says_so(monkeypatch, capsys, tmp_path):
    (tmp_path / "poses.txt").write_text("".join(f"1 0 0 {i} 0 1 0 0 0 0 1 0\n" for i in range(5)))
    monkeypatch.setattr(sys, "argv", ["evp", "info", str(tmp_path / "poses.txt")])
    with pytest.raises(SystemExit) as exited:
        main()
    assert not exited.value.code
    assert "ground truth: 5 poses, no times (KITTI poses: evp eval takes --ref-times/--est-times)" in capsys.readouterr().out


def test_a_folder_inside_a_dataset_names_the_dataset(monkeypatch, capsys, tmp_path):
    """KITTI's image_0 or EuRoC's mav0/cam0 given for the dataset: 'a folder of 51 images needs
    their times', or for cam0 a EuRoC data.csv read as a trajectory ('expected 8 or 9 or ... 39')."""
    from tests.io import builders

    root = builders.make_kitti(tmp_path / "kitti")
    (root / "image_0" / "data.csv").write_text("#timestamp [ns],filename\n1403636579763555584,1403636579763555584.png\n")
    code, err = evp_main(monkeypatch, capsys, "run", root / "image_0", "--out", tmp_path / "out")
    assert code == ExitCode.DATA
    assert one_line_error(err).endswith(f"image_0: a part of the kitti dataset {root}; give that folder")


def test_a_csv_of_the_wrong_width_says_the_range_it_takes(tmp_path):
    from evp.errors import TrajectoryFormatError

    (tmp_path / "data.csv").write_text("#timestamp [ns],filename\n1403636579763555584,1403636579763555584.png\n")
    with pytest.raises(TrajectoryFormatError, match="line 2: expected 8 to 39 values, found 2"):
        read_trajectory(tmp_path / "data.csv")


def test_a_flight_shorter_than_the_alignment_phase_says_how_to_shorten_it():
    """evp align on an 8 s simulated flight: the default phase (70 s after the target altitude) outlasts it."""
    from types import SimpleNamespace

    from evp.eval.flight_report import flight_summary
    from evp.fusion.gps_input import AlignmentError

    short = SimpleNamespace(errors_m=np.zeros(0), alignment=SimpleNamespace(window=(105.5, 175.5)), gps=SimpleNamespace(times=np.array([100.0, 108.0])))
    with pytest.raises(AlignmentError, match=r"phase \(5.5..75.5 s after the first fix\).*--align-fraction 0.33"):
        flight_summary(short)


def test_a_corrupt_video_is_one_line_without_ffmpegs_log(tmp_path):
    from tests.cli.conftest import evp

    (tmp_path / "flight.mp4").write_bytes(b"\x00\x00\x00\x18ftypmp42\x00\x00\x00\x00mp42isom" + bytes(3000))  # cut before its index (moov)
    result = evp("info", tmp_path / "flight.mp4")
    assert result.returncode == ExitCode.DATA
    assert one_line_error(result.stderr).endswith("flight.mp4: cannot open video (unsupported codec or corrupt file)")
    assert result.stdout == ""  # FFmpeg's "moov atom not found" came out on stdout, where results go
