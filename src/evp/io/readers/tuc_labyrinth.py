"""TU Chemnitz "Labyrinth" (libRSF's Indoor_UWB) as CSV: a small differential-drive robot's wheel
speeds, UWB ranges to four anchors and a 2-D ground-truth position track.

Files: ``wheel_odometry.csv`` (``t_s, v_right_wheel_mps, v_left_wheel_mps, v_y_mps, wheel_base_m,
cov_v_right, cov_v_left, cov_v_y``), ``uwb_ranges.csv`` (``t_s, range_m, range_cov_m2, anchor_x_m,
anchor_y_m, anchor_id, snr``) and ``groundtruth.csv`` (``t_s, x_m, y_m``).

Wheels: forward speed is the mean of the two wheel speeds; yaw rate is (v_left - v_right) /
(2 x wheel_base_m). That is libRSF's own model, and the one that turns with the ground truth: the
literal (v_right - v_left) / wheel_base turns the wrong way at twice the rate (the dataset's
README measured both). Each :class:`WheelOdometry` keeps the two wheel speeds as (left, right).

Anchors: their positions come with every range row; one anchor id at two different positions is
an error. Ranges to anchors with a non-finite or non-positive value are dropped with a warning.
Anchors lie on the ground plane (z = 0). The ground truth has positions only (identity rotations).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from evp.errors import DatasetError
from evp.io.beacon_ranges import beacon_range_records
from evp.io.dataset import Dataset, check_increasing
from evp.io.text_tables import read_table
from evp.types import Trajectory, WheelOdometry

WHEELS = "wheel_odometry.csv"
RANGES = "uwb_ranges.csv"
TRUTH = "groundtruth.csv"
ANCHOR_TOLERANCE_M = 1e-6  # the same anchor is written with the same digits on every row


class TucLabyrinthReader:
    name = "tuc-labyrinth"
    description = "TU Chemnitz Labyrinth as CSV (differential-drive wheel speeds, UWB ranges to anchors, 2-D ground truth)"
    looks_for = f"{WHEELS} and {RANGES}"

    def detect(self, path: Path) -> bool:
        return path.is_dir() and (path / WHEELS).is_file() and (path / RANGES).is_file()

    def read(self, path: Path) -> Dataset:
        dataset = Dataset(path.name, self.name, path)
        wheels, wheel_lines, _ = read_table(path / WHEELS, columns=8)
        check_increasing(path / WHEELS, wheels[:, 0], "wheel", wheel_lines)
        bad_base = np.flatnonzero(~(wheels[:, 4] > 0))
        if len(bad_base):
            raise DatasetError(path / WHEELS, f"wheel_base_m must be positive, found {wheels[bad_base[0], 4]!r}", line=wheel_lines[bad_base[0]])
        dataset.wheel = [
            WheelOdometry(float(t), (float(left), float(right)), float((left + right) / 2), float((left - right) / (2 * base)))
            for t, right, left, base in zip(wheels[:, 0], wheels[:, 1], wheels[:, 2], wheels[:, 4])
        ]
        ranges, range_lines, _ = read_table(path / RANGES, columns=7)
        names = [f"{ident:g}" for ident in ranges[:, 5]]
        for name, x, y, line in zip(names, ranges[:, 3], ranges[:, 4], range_lines):
            known = dataset.beacons.setdefault(name, (float(x), float(y), 0.0))
            if max(abs(known[0] - x), abs(known[1] - y)) > ANCHOR_TOLERANCE_M:
                raise DatasetError(path / RANGES, f"anchor {name} at ({x}, {y}) but earlier at ({known[0]}, {known[1]})", line=line)
        dataset.beacon_ranges = beacon_range_records(path / RANGES, ranges[:, 0], names, ranges[:, 1], range_lines, dataset.beacons, dataset.warnings)
        if (path / TRUTH).is_file():
            truth, truth_lines, _ = read_table(path / TRUTH, columns=3)
            check_increasing(path / TRUTH, truth[:, 0], "ground-truth", truth_lines)
            positions = np.column_stack([truth[:, 1:3], np.zeros(len(truth))])
            dataset.ground_truth = Trajectory(positions, np.tile([0.0, 0.0, 0.0, 1.0], (len(truth), 1)), truth[:, 0], "ground_truth")
            dataset.ground_truth_orientation = False
            dataset.ground_truth_note = "2-D robot positions (z = 0), no heading"
        dataset.notes.append("yaw rate = (v_left - v_right) / (2 x wheel_base), libRSF's differential-drive model")
        return dataset
