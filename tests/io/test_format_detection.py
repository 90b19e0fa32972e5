"""Each format's common variants are recognised, and detection never hands a path to the wrong reader."""

import numpy as np
import pytest

from evp.errors import AmbiguousFormatError, CalibrationError, TrajectoryFormatError, UnknownFormatError
from evp.io.readers.kitti import KITTI_FRAME_RATE_HZ
from evp.io.registry import detect_reader, open_dataset
from evp.io.trajectory import detect_trajectory_format
from tests.io import builders

# KITTI sequence 00's P0 and P2 (calib.txt of the odometry benchmark): one K, P2 offset by t = K^-1 P2[:, 3]
P0 = "P0: 718.856 0 607.1928 0 0 718.856 185.2157 0 0 0 1 0"
P2 = "P2: 718.856 0 607.1928 45.38225 0 718.856 185.2157 -0.1130887 0 0 1 0.003779761"


def test_kitti_without_times_gets_nominal_stamps_and_a_warning(tmp_path):
    root = builders.make_kitti(tmp_path / "06")
    (root / "times.txt").unlink()
    assert detect_reader(root).name == "kitti"
    dataset = open_dataset(root)
    assert np.allclose(dataset.frame_times, np.arange(5) / KITTI_FRAME_RATE_HZ)
    assert any("no times.txt" in w and "10 Hz" in w for w in dataset.warnings)
    assert np.allclose(dataset.ground_truth.timestamps, dataset.frame_times)


def test_kitti_colour_only_download_reads_image_2_with_p2(tmp_path):
    root = builders.make_kitti(tmp_path / "00")
    (root / "image_0").rename(root / "image_2")
    (root / "calib.txt").write_text(f"{P0}\n{P2}\n")
    dataset = open_dataset(root)
    assert dataset.camera.name == "kitti_cam2" and dataset.camera.fx == 718.856
    t = np.linalg.solve([[718.856, 0, 607.1928], [0, 718.856, 185.2157], [0, 0, 1]], [45.38225, -0.1130887, 0.003779761])
    cam0 = np.array([[0.0, 0.0, float(i)] for i in range(5)])  # poses.txt: identity rotations, z = i
    assert np.allclose(dataset.ground_truth.positions, cam0 - t)  # camera 2's centre is at -t in camera 0's frame
    (root / "calib.txt").write_text(f"{P0}\n")
    with pytest.raises(CalibrationError, match="no 'P2:' line"):
        open_dataset(root)


def test_kitti_benchmark_layout_finds_its_poses(tmp_path):
    root = builders.make_kitti(tmp_path / "dataset" / "sequences" / "03")
    (tmp_path / "dataset" / "poses").mkdir()
    (root / "poses.txt").rename(tmp_path / "dataset" / "poses" / "03.txt")
    dataset = open_dataset(root)
    assert dataset.ground_truth is not None and "03.txt" in dataset.ground_truth_note


def test_euroc_without_data_csv_takes_times_from_image_names(tmp_path):
    root = builders.make_euroc(tmp_path / "MH_01")
    (root / "mav0/cam0/data.csv").unlink()
    assert detect_reader(root).name == "euroc"
    dataset = open_dataset(root)
    assert np.allclose(dataset.frame_times, 1000.0 + 0.05 * np.arange(5))
    assert any("data.csv" in n for n in dataset.notes)


def test_a_folder_two_readers_claim_is_refused_naming_both(tmp_path):
    root = builders.make_kitti(tmp_path / "ds")
    (root / "rgb.txt").write_text("0.0 image_0/000000.png\n")
    with pytest.raises(AmbiguousFormatError, match="tum-rgbd .*and kitti .*--format tum-rgbd or --format kitti"):
        open_dataset(root)
    assert open_dataset(root, "kitti").format == "kitti"


def test_geotagged_photos_with_a_timestamps_file_are_ambiguous(tmp_path):
    root = builders.make_exif_photos(tmp_path / "ds")
    (root / "images.txt").write_text("".join(f"{i}.0 IMG_{i:04d}.jpg\n" for i in range(4)))
    with pytest.raises(AmbiguousFormatError, match="image-folder .*exif-photos"):
        detect_reader(root)


def test_a_folder_no_reader_claims_says_what_each_looked_for(tmp_path):
    (tmp_path / "image_0").mkdir()  # KITTI images without times.txt or a KITTI calib.txt
    with pytest.raises(UnknownFormatError, match="kitti: image_0/ or image_2/, with times.txt") as info:
        detect_reader(tmp_path)
    assert "euroc: mav0/cam0/data.csv" in str(info.value) and "image-folder: images" in str(info.value)


def test_image_folder_reads_a_kitti_calib_txt_as_p0(tmp_path):
    root = builders.make_image_folder(tmp_path / "ds")
    (root / "calib.txt").write_text("P0: 335.4 0 129.9 0 0 335.3 99.2 0 0 0 1 0\nP1: 335.4 0 129.9 -100 0 335.3 99.2 0 0 0 1 0\n")
    dataset = open_dataset(root)
    assert (dataset.camera.fx, dataset.camera.fy, dataset.camera.cx) == (335.4, 335.3, 129.9)
    assert any("KITTI form" in n for n in dataset.notes)
    (root / "calib.txt").write_text("P1: 335.4 0 129.9 -100 0 335.3 99.2 0 0 0 1 0\n")
    with pytest.raises(CalibrationError, match="no 'P0:' line"):
        open_dataset(root)


def test_a_kitti_calib_txt_is_not_a_trajectory(tmp_path):
    path = tmp_path / "calib.txt"
    path.write_text(f"{P0}\n")
    with pytest.raises(TrajectoryFormatError, match="not a trajectory: the first value 'P0:'"):
        detect_trajectory_format(path)
    (tmp_path / "poses.txt").write_text("1 0 0 0 0 1 0 0 0 0 1 0\n1 0 0 1 0 1 0 0 0 0 1 0\n")
    dataset = open_dataset(tmp_path)
    assert dataset.format == "trajectories" and list(dataset.trajectories) == ["poses.txt"]
