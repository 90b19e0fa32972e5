"""Malformed input of every format raises a specific error that names the file and line/record."""

from pathlib import Path

import numpy as np
import pytest

from evp.errors import CalibrationError, DatasetError, TrajectoryFormatError, UnknownFormatError, UsageError
from evp.io.dataset import load_image
from evp.io.registry import detect_reader, open_dataset
from evp.io.telemetry_csv import read_telemetry_csv
from tests.io import builders


def _replace_line(path: Path, index: int, text: str) -> None:
    lines = path.read_text().splitlines()
    lines[index] = text
    path.write_text("\n".join(lines) + "\n")


@pytest.mark.parametrize(
    "builder, fmt",
    [
        (builders.make_image_folder, "image-folder"),
        (builders.make_euroc, "euroc"),
        (builders.make_kitti, "kitti"),
        (builders.make_tum_rgbd, "tum-rgbd"),
        (builders.make_exif_photos, "exif-photos"),
    ],
)
def test_valid_builders_load(tmp_path, builder, fmt):
    path = builder(tmp_path / "ds")
    assert detect_reader(path).name == fmt
    dataset = open_dataset(path)
    assert dataset.num_frames > 0
    assert len(list(dataset.frames())) == dataset.num_frames


@pytest.mark.parametrize(
    "builder, file, index, text, error, message",
    [
        (builders.make_euroc, "mav0/cam0/data.csv", 3, "12x45,foo.png", DatasetError, "bad timestamp"),
        (builders.make_euroc, "mav0/imu0/data.csv", 5, "1000020000000,0,0,0.1,0,0", DatasetError, "expected 7 values"),
        (builders.make_kitti, "poses.txt", 2, "1 0 0 0 0 1 0 0 0 0 1", TrajectoryFormatError, None),
        (builders.make_tum_rgbd, "rgb.txt", 5, "13050311O2.2 rgb/x.png", DatasetError, "bad timestamp"),
        (builders.make_tum_rgbd, "groundtruth.txt", 4, "1305031102.2 0 0 0 0 0 1", TrajectoryFormatError, "expected 8 values"),
    ],
)
def test_bad_line_names_the_file_and_line(tmp_path, builder, file, index, text, error, message):
    root = builder(tmp_path / "ds")
    _replace_line(root / file, index, text)
    with pytest.raises(error, match=message) as info:
        open_dataset(root)
    assert info.value.line == index + 1 and info.value.path.name == Path(file).name


def test_euroc_missing_image_is_reported(tmp_path):
    root = builders.make_euroc(tmp_path / "ds")
    next((root / "mav0/cam0/data").glob("*.png")).unlink()
    with pytest.raises(DatasetError, match="missing"):
        open_dataset(root)


def test_euroc_sensor_log_with_no_rows_is_a_sensor_that_recorded_nothing(tmp_path):
    """A GPS jammed from take-off leaves its header and no fixes: read as no GPS, said once; a
    malformed row in the same log is still an error with its line."""
    root = builders.make_euroc(tmp_path / "ds")
    (root / "mav0/gps0").mkdir()
    log = root / "mav0/gps0/data.csv"
    log.write_text("#timestamp [ns],latitude [deg],longitude [deg],altitude [m],h_acc [m],v_acc [m]\n")
    dataset = open_dataset(root)
    assert dataset.gps == [] and any("gps0/data.csv has no rows" in w for w in dataset.warnings)
    log.write_text(log.read_text() + "1000000000,41.5,-83.7\n")
    with pytest.raises(DatasetError, match="expected 6 values"):
        open_dataset(root)


def test_euroc_corrupt_image_fails_when_decoded(tmp_path):
    root = builders.make_euroc(tmp_path / "ds")
    victim = sorted((root / "mav0/cam0/data").glob("*.png"))[2]
    victim.write_bytes(b"\x89PNG\r\n\x1a\n broken")
    dataset = open_dataset(root)
    frames = dataset.frames()
    next(frames), next(frames)
    with pytest.raises(DatasetError, match="cannot be decoded") as info:
        next(frames)
    assert info.value.path == victim


def test_euroc_sensor_yaml_without_intrinsics(tmp_path):
    root = builders.make_euroc(tmp_path / "ds")
    text = (root / "mav0/cam0/sensor.yaml").read_text().replace("intrinsics: [335.4, 335.3, 129.9, 99.2]\n", "")
    (root / "mav0/cam0/sensor.yaml").write_text(text)
    with pytest.raises(CalibrationError, match="sensor.yaml"):
        open_dataset(root)


def test_euroc_non_monotonic_image_times(tmp_path):
    root = builders.make_euroc(tmp_path / "ds")
    lines = (root / "mav0/cam0/data.csv").read_text().splitlines()
    lines[2], lines[3] = lines[3], lines[2]
    (root / "mav0/cam0/data.csv").write_text("\n".join(lines) + "\n")
    with pytest.raises(DatasetError, match="must increase") as info:
        open_dataset(root)
    assert info.value.line == 4


def test_kitti_calib_without_p0(tmp_path):
    root = builders.make_kitti(tmp_path / "ds")
    (root / "calib.txt").write_text("P1: 1 0 0 0 0 1 0 0 0 0 1 0\n")
    with pytest.raises(CalibrationError, match="P0"):
        open_dataset(root)


def test_kitti_too_few_times(tmp_path):
    root = builders.make_kitti(tmp_path / "ds")
    (root / "times.txt").write_text("0.0\n0.1\n")
    with pytest.raises(DatasetError, match="2 times for 5 images"):
        open_dataset(root)


def test_tum_known_kinect_intrinsics_are_used(tmp_path):
    root = builders.make_tum_rgbd(tmp_path / "rgbd_dataset_freiburg1_xyz")
    dataset = open_dataset(root)
    assert dataset.camera.fx == 517.3 and len(dataset.imu) == 20


def test_image_folder_without_calibration(tmp_path):
    """It reads (evp info shows it, --camera can complete it); a run without a camera is refused."""
    from evp.config import Settings
    from evp.run_setup import camera_for

    root = builders.make_image_folder(tmp_path / "ds")
    (root / "calib.txt").unlink()
    dataset = open_dataset(root)
    assert dataset.camera is None and any("no calibration file" in note for note in dataset.notes)
    with pytest.raises(CalibrationError, match="give --camera FILE"):
        camera_for(dataset, Settings())


def test_image_folder_calibration_for_another_resolution(tmp_path):
    root = builders.make_image_folder(tmp_path / "ds")
    (root / "calib.txt").unlink()
    (root / "camera.yaml").write_text("image_width: 640\nimage_height: 480\ncamera_matrix: {rows: 3, cols: 3, data: [500, 0, 320, 0, 500, 240, 0, 0, 1]}\n")
    with pytest.raises(CalibrationError, match="640x480 but images are 240x180"):
        open_dataset(root)


def test_image_folder_wrong_calibration_numbers(tmp_path):
    root = builders.make_image_folder(tmp_path / "ds")
    (root / "calib.txt").write_text("335.4 335.3 129.9\n")
    with pytest.raises(CalibrationError, match="found 3") as info:
        open_dataset(root)
    assert info.value.line == 1


def test_exif_photo_without_gps(tmp_path):
    root = builders.make_exif_photos(tmp_path / "ds")
    builders.write_geotagged_jpeg(root / "IMG_9999.jpg", 50, 0, 0, 0, gps=False)
    with pytest.raises(DatasetError, match="no EXIF GPS") as info:
        open_dataset(root, "exif-photos")
    assert info.value.path.name == "IMG_9999.jpg" and info.value.record == "GPSInfo"


def test_corrupt_video(tmp_path):
    path = tmp_path / "broken.mp4"
    path.write_bytes(b"\x00\x00\x00\x18ftypmp42" + b"\x13" * 500)
    with pytest.raises(DatasetError, match="cannot open video|no frames"):
        open_dataset(path)


@pytest.mark.parametrize("name", ["broken.bag", "broken.mcap"])
def test_corrupt_bags(tmp_path, name):
    path = tmp_path / name
    path.write_bytes(b"garbage" * 100)
    with pytest.raises(DatasetError, match="cannot read bag"):
        open_dataset(path)


def test_telemetry_csv_errors_name_the_line(tmp_path):
    path = tmp_path / "t.csv"
    path.write_text("timestamp,sensor,values...\n0.0,imu,0,0,0,0,0,9.8\n0.1,gps,91.0,10.0,100\n")
    with pytest.raises(DatasetError, match="out of range") as info:
        read_telemetry_csv(path)
    assert info.value.line == 3
    path.write_text("0.0,imu,0,0,0,0,0,9.8\n0.1,lidar,1,2\n")
    with pytest.raises(DatasetError, match="unknown sensor"):
        read_telemetry_csv(path)
    path.write_text("0.2,baro,101325\n0.1,baro,101320\n")
    with pytest.raises(DatasetError, match="earlier"):
        read_telemetry_csv(path)


def test_unknown_paths(tmp_path):
    with pytest.raises(UnknownFormatError, match="no such file"):
        open_dataset(tmp_path / "nothing")
    (tmp_path / "notes").mkdir()
    (tmp_path / "notes" / "a.md").write_text("hello")
    with pytest.raises(UnknownFormatError, match="no images, video or recording here"):
        open_dataset(tmp_path / "notes")
    with pytest.raises(UsageError, match="no such dataset format; known: euroc"):
        open_dataset(tmp_path / "notes", "lidar-scans")
    with pytest.raises(UsageError, match="did you mean kitti?"):
        open_dataset(tmp_path / "notes", "kitty")


def test_hostile_offline_input_is_one_specific_error_line(tmp_path):
    """Issue 34: a binary images.txt and a random .bag gave tracebacks; all-NaN timestamps were
    accepted and written as nan; a 20000x20000 PNG was decoded whole before it was skipped."""
    from tests.cli.conftest import evp

    binary = builders.make_image_folder(tmp_path / "binary")
    (binary / "images.txt").write_bytes(bytes(range(256)) * 8)
    with pytest.raises(DatasetError, match="not a text file"):
        open_dataset(binary)
    bag = tmp_path / "random.bag"
    bag.write_bytes(np.random.default_rng(3).bytes(5000))
    with pytest.raises(DatasetError, match="cannot read bag: not a ROS 1 bag"):
        open_dataset(bag)
    for path in (binary, bag):
        result = evp("run", path, "--out", tmp_path / "out")
        assert result.returncode == 3 and "Traceback" not in result.stderr, result.stderr
        assert len(result.stderr.strip().splitlines()) == 1 and str(path.name) in result.stderr

    nan = builders.make_image_folder(tmp_path / "nan")
    names = [line.split()[1] for line in (nan / "images.txt").read_text().splitlines()]
    (nan / "images.txt").write_text("".join(f"nan {name}\n" for name in names))
    with pytest.raises(DatasetError, match="timestamp nan is not a finite number") as info:
        open_dataset(nan)
    assert info.value.line == 1

    huge = builders.make_image_folder(tmp_path / "huge")
    first = sorted((huge / "images").iterdir())[0]
    first.write_bytes(builders.png_header_only(20000, 20000))
    with pytest.raises(DatasetError, match="20000x20000 pixels: more than 134 Mpx, not decoded"):
        load_image(first)
