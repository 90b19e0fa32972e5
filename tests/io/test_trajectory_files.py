import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from evp.errors import TrajectoryFormatError
from evp.io.trajectory import (
    TrajectoryFormat,
    detect_trajectory_format,
    read_trajectory,
    tum_text,
    write_trajectory,
)
from evp.types import Trajectory


def _random_trajectory(n=50, seed=0):
    rng = np.random.default_rng(seed)
    quats = Rotation.random(n, random_state=seed).as_quat()
    quats[quats[:, 3] < 0] *= -1
    stamps = 1403636584.0 + np.cumsum(rng.uniform(0.01, 0.1, n))
    return Trajectory(rng.normal(0, 100, (n, 3)), quats, stamps, "random")


def test_tum_round_trip_is_exact(tmp_path):
    trajectory = _random_trajectory()
    write_trajectory(tmp_path / "t.tum", trajectory, TrajectoryFormat.TUM)
    assert detect_trajectory_format(tmp_path / "t.tum") is TrajectoryFormat.TUM
    back = read_trajectory(tmp_path / "t.tum")
    assert np.array_equal(back.timestamps, trajectory.timestamps)
    assert np.array_equal(back.positions, trajectory.positions)
    assert np.allclose(back.quats_xyzw, trajectory.quats_xyzw, atol=1e-15)


def test_csv_round_trip_is_exact(tmp_path):
    trajectory = _random_trajectory(seed=1)
    write_trajectory(tmp_path / "t.csv", trajectory, TrajectoryFormat.CSV)
    assert detect_trajectory_format(tmp_path / "t.csv") is TrajectoryFormat.CSV
    back = read_trajectory(tmp_path / "t.csv")
    assert np.array_equal(back.timestamps, trajectory.timestamps)
    assert np.array_equal(back.positions, trajectory.positions)


def test_kitti_round_trip_keeps_poses(tmp_path):
    trajectory = _random_trajectory(seed=2)
    write_trajectory(tmp_path / "t.txt", trajectory, TrajectoryFormat.KITTI)
    assert detect_trajectory_format(tmp_path / "t.txt") is TrajectoryFormat.KITTI
    back = read_trajectory(tmp_path / "t.txt")
    assert back.timestamps is None
    assert np.allclose(back.poses, trajectory.poses, atol=1e-12)


def test_kitti_with_frame_index_column_keeps_the_index(tmp_path):
    rows = [f"{i} 1 0 0 {i} 0 1 0 0 0 0 1 0" for i in (0, 2, 5)]
    (tmp_path / "est.txt").write_text("\n".join(rows) + "\n")
    trajectory = read_trajectory(tmp_path / "est.txt")
    assert trajectory.timestamps.tolist() == [0, 2, 5]
    assert trajectory.positions[:, 0].tolist() == [0, 2, 5]


def test_euroc_csv_quaternion_is_scalar_first(tmp_path):
    (tmp_path / "gt.csv").write_text("#timestamp,p_x,p_y,p_z,q_w,q_x,q_y,q_z\n1000000000,1,2,3,0,1,0,0\n2000000000,1,2,4,1,0,0,0\n")
    trajectory = read_trajectory(tmp_path / "gt.csv")
    assert trajectory.timestamps.tolist() == [1.0, 2.0]
    assert np.allclose(trajectory.quats_xyzw[0], [1, 0, 0, 0])


@pytest.mark.parametrize(
    "content, line, message",
    [
        ("0 0 0 0 0 0 0 1\n1 0 0 0 0 0 1\n", 2, "expected 8 values"),
        ("0 0 0 0 0 0 0 1\n1 0 x 0 0 0 0 1\n", 2, "not a number"),
        ("# header\n0 0 0 0 0 0 0 1\n1 0 nan 0 0 0 0 1\n", 3, "NaN"),
        ("1 0 0 0 0 0 0 1\n0 0 0 0 0 0 0 1\n", 2, "backwards"),
        ("0 0 0 0 0 0 0 1\n1 0 0 0 0 0 0 2\n", 2, "quaternion norm"),
        ("0 0 0 0 0\n", 1, "unrecognised"),
        ("1 0 0 0 0 1 0 0 0 0 2 0\n", 1, "determinant"),
    ],
)
def test_malformed_trajectories_name_file_and_line(tmp_path, content, line, message):
    path = tmp_path / "bad.txt"
    path.write_text(content)
    with pytest.raises(TrajectoryFormatError, match=message) as info:
        read_trajectory(path)
    assert info.value.line == line
    assert str(path) in str(info.value)


def test_empty_and_binary_files_are_rejected(tmp_path):
    (tmp_path / "empty.txt").write_text("# nothing\n")
    with pytest.raises(TrajectoryFormatError, match="no poses"):
        read_trajectory(tmp_path / "empty.txt")
    (tmp_path / "binary.txt").write_bytes(b"\xff\xfe\x00\x81" * 10)
    with pytest.raises(TrajectoryFormatError, match="not a text file"):
        read_trajectory(tmp_path / "binary.txt")


def test_tum_writer_needs_timestamps(tmp_path):
    trajectory = _random_trajectory()
    with pytest.raises(ValueError, match="timestamps"):
        write_trajectory(tmp_path / "x.tum", Trajectory(trajectory.positions, trajectory.quats_xyzw), TrajectoryFormat.TUM)


def test_tum_text_is_the_file_and_an_empty_trajectory_is_its_header(tmp_path):
    trajectory = _random_trajectory(5)
    write_trajectory(tmp_path / "t.tum", trajectory, TrajectoryFormat.TUM)
    assert tum_text(trajectory) == (tmp_path / "t.tum").read_text()
    assert tum_text(Trajectory(np.zeros((0, 3)), np.zeros((0, 4)), np.zeros(0))) == "# timestamp tx ty tz qx qy qz qw\n"
