"""CMU ranging-radio sets (Djugash et al. 2009, "Plaza1"/"Plaza2" as redistributed by GTSAM) as
CSV: a ground vehicle's odometry increments, time-of-flight ranges to four surveyed radio nodes
and a 2-D ground-truth track, all in one local metric frame.

Files share a prefix (``plaza1_``): ``<p>odometry_DR.csv`` (``t_s, delta_distance_m,
delta_heading_rad``), ``<p>ranges_TD.csv`` (``t_s, sender_id, beacon_id, range_m``),
``<p>beacons_TL.csv`` (``beacon_id, x_m, y_m``) and ``<p>groundtruth_GT.csv`` (``t_s, x_m, y_m,
theta_rad``).

Odometry: each DR row holds the distance and heading change over the interval that ends at its
time and starts at the previous row's time. It becomes one :class:`WheelOdometry` stamped at the
end of that interval whose forward speed and yaw rate are the increment divided by the interval
(the mean over it, so integrating speed x interval gives the increments back exactly). The first
row's interval starts at the ground truth's first time, the only earlier time the files give
(the ground truth starts one step before the odometry). There are no individual wheel speeds.

Ranges: the upstream file is not in time order (Plaza1 has two blocks that restart about a minute
earlier); rows are sorted by time, with a warning. Rows naming a beacon that is not in the
beacon list, or with a range that is not a finite positive number, are dropped with a warning,
the others kept. Beacons lie on the ground plane (z = 0): the files give no heights.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from evp.errors import DatasetError
from evp.io.beacon_ranges import beacon_range_records
from evp.io.dataset import Dataset, check_increasing
from evp.io.text_tables import read_table
from evp.types import Trajectory, WheelOdometry

SUFFIXES = ("odometry_DR.csv", "ranges_TD.csv", "beacons_TL.csv", "groundtruth_GT.csv")


def _prefixes(path: Path) -> list[str]:
    """File-name prefixes for which every one of the four files is present."""
    if not path.is_dir():
        return []
    candidates = {p.name.removesuffix(SUFFIXES[0]) for p in path.glob(f"*{SUFFIXES[0]}")}
    return sorted(prefix for prefix in candidates if all((path / f"{prefix}{suffix}").is_file() for suffix in SUFFIXES))


class CmuPlazaReader:
    name = "cmu-plaza"
    description = "CMU ranging-radio set as CSV (odometry increments, radio ranges to surveyed nodes, 2-D ground truth)"
    looks_for = "*odometry_DR.csv, *ranges_TD.csv, *beacons_TL.csv and *groundtruth_GT.csv with one prefix"

    def detect(self, path: Path) -> bool:
        return len(_prefixes(path)) == 1

    def read(self, path: Path) -> Dataset:
        prefixes = _prefixes(path)
        if len(prefixes) != 1:
            raise DatasetError(path, f"expected one set of {', '.join('*' + s for s in SUFFIXES)}, found {len(prefixes)}")
        prefix = prefixes[0]
        dataset = Dataset(path.name, self.name, path)
        truth_path = path / f"{prefix}groundtruth_GT.csv"
        truth, truth_lines, _ = read_table(truth_path, columns=4)
        check_increasing(truth_path, truth[:, 0], "ground-truth", truth_lines)
        yaw = Rotation.from_euler("z", truth[:, 3:4]).as_quat()
        dataset.ground_truth = Trajectory(np.column_stack([truth[:, 1:3], np.zeros(len(truth))]), yaw, truth[:, 0], "ground_truth")
        dataset.ground_truth_orientation = False
        dataset.ground_truth_note = "2-D vehicle track (z = 0); its heading is the odometry's own integrated heading, only positions are independent"
        odometry_path = path / f"{prefix}odometry_DR.csv"
        odometry, odometry_lines, _ = read_table(odometry_path, columns=3)
        check_increasing(odometry_path, odometry[:, 0], "odometry", odometry_lines)
        starts = np.concatenate([[truth[0, 0]], odometry[:-1, 0]])
        if starts[0] >= odometry[0, 0]:
            raise DatasetError(odometry_path, "the first increment ends before the ground truth starts: its interval is unknown", line=odometry_lines[0])
        intervals = odometry[:, 0] - starts
        dataset.wheel = [
            WheelOdometry(float(t), (), float(d / dt), float(h / dt)) for (t, d, h), dt in zip(odometry, intervals)
        ]  # fmt: skip
        beacon_path = path / f"{prefix}beacons_TL.csv"
        beacons, beacon_lines, _ = read_table(beacon_path, columns=3)
        for (ident, x, y), line in zip(beacons, beacon_lines):
            name = f"{ident:g}"
            if name in dataset.beacons:
                raise DatasetError(beacon_path, f"beacon {name} is listed twice", line=line)
            dataset.beacons[name] = (float(x), float(y), 0.0)
        ranges_path = path / f"{prefix}ranges_TD.csv"
        ranges, range_lines, _ = read_table(ranges_path, columns=4)
        names = [f"{ident:g}" for ident in ranges[:, 2]]
        dataset.beacon_ranges = beacon_range_records(ranges_path, ranges[:, 0], names, ranges[:, 3], range_lines, dataset.beacons, dataset.warnings)
        dataset.notes.append(f"odometry increments as mean speed and yaw rate over each interval; {len(dataset.beacons)} radio nodes on the ground plane")
        return dataset
