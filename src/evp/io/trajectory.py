"""Trajectory file formats: TUM, KITTI, EuRoC ground-truth CSV and EVP CSV.

Formats are recognised from the content, not the file name:

* TUM: ``timestamp tx ty tz qx qy qz qw`` (space separated, quaternion scalar last)
* KITTI: 12 numbers, the row-major 3x4 ``[R|t]``; a 13th leading number is a frame index,
  kept as the pose's timestamp so that such files match ground truth by frame
* EuRoC: ``timestamp_ns, px, py, pz, qw, qx, qy, qz, ...`` (comma separated, scalar first)
* EVP CSV: header ``timestamp,tx,ty,tz,qx,qy,qz,qw``
"""

from __future__ import annotations

import enum
from pathlib import Path

import numpy as np

from evp.errors import TrajectoryFormatError
from evp.io.text_tables import read_text_file
from evp.types import Trajectory


class TrajectoryFormat(enum.Enum):
    TUM = "tum"
    KITTI = "kitti"
    EUROC = "euroc"
    CSV = "csv"


CSV_HEADER = "timestamp,tx,ty,tz,qx,qy,qz,qw"


def _data_lines(path: Path) -> list[tuple[int, str]]:
    """(1-based line number, text) of the non-empty, non-comment lines of a file."""
    text = read_text_file(path, TrajectoryFormatError)
    lines = []
    for number, raw in enumerate(text.splitlines(), start=1):
        stripped = raw.strip()
        if stripped and not stripped.startswith("#") and not stripped.startswith("%"):
            lines.append((number, stripped))
    return lines


def _parse_rows(path: Path, lines: list[tuple[int, str]], separator: str | None, columns: set[int]) -> np.ndarray:
    """Parse numeric rows, each with one of the allowed column counts, naming the bad line."""
    rows = []
    width = None
    for number, text in lines:
        fields = [f for f in (text.split(separator) if separator else text.split()) if f.strip() != ""]
        if width is None:
            width = len(fields)
            if width not in columns:
                counts = sorted(columns)
                expected = (
                    f"{counts[0]} to {counts[-1]}" if len(counts) > 2 and counts == list(range(counts[0], counts[-1] + 1)) else " or ".join(map(str, counts))
                )
                raise TrajectoryFormatError(path, f"expected {expected} values, found {width}", line=number)
        elif len(fields) != width:
            raise TrajectoryFormatError(path, f"expected {width} values like the first row, found {len(fields)}", line=number)
        try:
            values = [float(f) for f in fields]
        except ValueError as exc:
            raise TrajectoryFormatError(path, f"not a number: {exc}", line=number) from exc
        if not np.all(np.isfinite(values)):
            raise TrajectoryFormatError(path, "NaN or infinite value", line=number)
        rows.append(values)
    if not rows:
        raise TrajectoryFormatError(path, "no poses in file")
    return np.array(rows, dtype=float)


def detect_trajectory_format(path: Path) -> TrajectoryFormat:
    """Recognise the format of a trajectory file from its first data line."""
    path = Path(path)
    lines = _data_lines(path)
    if not lines:
        raise TrajectoryFormatError(path, "no poses in file")
    number, first = lines[0]
    if first.replace(" ", "").lower().startswith(CSV_HEADER):
        return TrajectoryFormat.CSV
    fields = first.split(",") if "," in first else first.split()
    try:
        float(fields[0])
    except ValueError:  # a label such as KITTI calib.txt's "P0:", or another table's header: not poses
        raise TrajectoryFormatError(path, f"not a trajectory: the first value {fields[0]!r} is not a number", line=number) from None
    if "," in first:
        return TrajectoryFormat.EUROC
    count = len(fields)
    if count == 8:
        return TrajectoryFormat.TUM
    if count in (12, 13):
        return TrajectoryFormat.KITTI
    raise TrajectoryFormatError(path, f"unrecognised trajectory format: {count} values per line (TUM has 8, KITTI 12)", line=number)


def _check_quaternions(path: Path, lines: list[tuple[int, str]], quats: np.ndarray) -> np.ndarray:
    norms = np.linalg.norm(quats, axis=1)
    bad = np.flatnonzero(np.abs(norms - 1.0) > 0.1)
    if len(bad):
        raise TrajectoryFormatError(path, f"quaternion norm {norms[bad[0]]:.3f} is not 1", line=lines[bad[0]][0])
    return quats / norms[:, None]


def _check_monotonic(path: Path, lines: list[tuple[int, str]], stamps: np.ndarray) -> None:
    back = np.flatnonzero(np.diff(stamps) < 0)
    if len(back):
        raise TrajectoryFormatError(path, "timestamps go backwards", line=lines[back[0] + 1][0])


def read_trajectory(path: str | Path, fmt: TrajectoryFormat | None = None) -> Trajectory:
    """Read a trajectory file, detecting its format unless given."""
    path = Path(path)
    fmt = fmt or detect_trajectory_format(path)
    lines = _data_lines(path)
    name = path.stem
    if fmt is TrajectoryFormat.TUM:
        rows = _parse_rows(path, lines, None, {8})
        _check_monotonic(path, lines, rows[:, 0])
        return Trajectory(rows[:, 1:4], _check_quaternions(path, lines, rows[:, 4:8]), rows[:, 0], name)
    if fmt is TrajectoryFormat.CSV:
        rows = _parse_rows(path, lines[1:], ",", {8})
        _check_monotonic(path, lines[1:], rows[:, 0])
        return Trajectory(rows[:, 1:4], _check_quaternions(path, lines[1:], rows[:, 4:8]), rows[:, 0], name)
    if fmt is TrajectoryFormat.EUROC:
        rows = _parse_rows(path, lines, ",", set(range(8, 40)))
        stamps = rows[:, 0] / 1e9
        _check_monotonic(path, lines, stamps)
        quats = _check_quaternions(path, lines, rows[:, [5, 6, 7, 4]])
        return Trajectory(rows[:, 1:4], quats, stamps, name)
    rows = _parse_rows(path, lines, None, {12, 13})
    matrices = rows[:, -12:].reshape(-1, 3, 4)
    det = np.linalg.det(matrices[:, :, :3])
    bad = np.flatnonzero(np.abs(det - 1.0) > 0.05)
    if len(bad):
        raise TrajectoryFormatError(path, f"rotation part has determinant {det[bad[0]]:.3f}, not 1", line=lines[bad[0]][0])
    poses = np.tile(np.eye(4), (len(rows), 1, 1))
    poses[:, :3, :] = matrices
    frame_index = rows[:, 0] if rows.shape[1] == 13 else None  # kitti-odom-eval's leading frame index
    return Trajectory.from_poses(poses, frame_index, name)


def read_timestamps(path: str | Path) -> np.ndarray:
    """One time in seconds per line (KITTI ``times.txt``)."""
    path = Path(path)
    lines = _data_lines(path)
    return _parse_rows(path, lines, None, {1})[:, 0]


def _num(value: float) -> str:
    """Shortest text that reads back as exactly the same float64."""
    return repr(float(value))


def tum_text(trajectory: Trajectory) -> str:
    """The trajectory in TUM format at full float64 precision (needs timestamps), header line first."""
    if trajectory.timestamps is None:
        raise ValueError("TUM files need timestamps; this trajectory has none")
    rows = np.column_stack([trajectory.timestamps, trajectory.positions, trajectory.quats_xyzw])
    return "# timestamp tx ty tz qx qy qz qw\n" + "".join(" ".join(_num(v) for v in row) + "\n" for row in rows)


def write_tum(path: str | Path, trajectory: Trajectory) -> None:
    """TUM file at full float64 precision (needs timestamps)."""
    Path(path).write_text(tum_text(trajectory))


def write_kitti(path: str | Path, trajectory: Trajectory) -> None:
    """KITTI format: 12 numbers per pose, row-major 3x4 ``[R|t]``; timestamps are not kept."""
    poses = trajectory.poses[:, :3, :].reshape(-1, 12)
    Path(path).write_text("".join(" ".join(_num(v) for v in row) + "\n" for row in poses))


def write_csv(path: str | Path, trajectory: Trajectory) -> None:
    """CSV with a header; a trajectory without timestamps gets its pose index as time."""
    stamps = trajectory.timestamps if trajectory.timestamps is not None else np.arange(len(trajectory), dtype=float)
    rows = np.column_stack([stamps, trajectory.positions, trajectory.quats_xyzw])
    Path(path).write_text(CSV_HEADER + "\n" + "".join(",".join(_num(v) for v in row) + "\n" for row in rows))


WRITERS = {TrajectoryFormat.TUM: write_tum, TrajectoryFormat.KITTI: write_kitti, TrajectoryFormat.CSV: write_csv}


def write_trajectory(path: str | Path, trajectory: Trajectory, fmt: TrajectoryFormat = TrajectoryFormat.TUM) -> None:
    if fmt not in WRITERS:
        raise ValueError(f"cannot write {fmt.value} trajectories; choose one of {[f.value for f in WRITERS]}")
    WRITERS[fmt](path, trajectory)
