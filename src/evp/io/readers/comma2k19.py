"""comma2k19 segments converted to CSV (phone-class IMU, GNSS, CAN wheel speeds, INS ground truth).

One common clock (``t_boot_s``). IMU axes are the device frame [forward, right, down]. No video.
The ground truth's ENU frame has its origin at the first ground-truth position (the README); that
origin, read from ``groundtruth_camera_ecef.csv``, is ``Dataset.enu_origin``, so GNSS fixes can be
put in the same frame.
"""

from __future__ import annotations

from pathlib import Path

import pymap3d

from evp.io.dataset import Dataset
from evp.io.text_tables import read_table
from evp.io.trajectory import read_trajectory
from evp.types import CameraModel, GpsFix, ImuSample, WheelOdometry

ROAD_CAMERA = CameraModel(1164, 874, 910.0, 910.0, 582.0, 437.0, name="comma_eon_road")


class Comma2k19Reader:
    name = "comma2k19"
    description = "comma2k19 segment as CSV (imu.csv, gnss_ublox_fix.csv, can_wheel_speeds.csv, INS ground truth)"
    looks_for = "imu.csv and gnss_ublox_fix.csv"

    def detect(self, path: Path) -> bool:
        return path.is_dir() and (path / "imu.csv").is_file() and (path / "gnss_ublox_fix.csv").is_file()

    def read(self, path: Path) -> Dataset:
        dataset = Dataset(path.name, self.name, path, ROAD_CAMERA)
        dataset.notes.append("no video in this segment; camera intrinsics are comma's published road-camera values")
        imu, _, _ = read_table(path / "imu.csv", min_columns=7)
        dataset.imu = [ImuSample(r[0], tuple(r[4:7]), tuple(r[1:4])) for r in imu]
        gnss, _, _ = read_table(path / "gnss_ublox_fix.csv", min_columns=6)
        dataset.gps = [GpsFix(r[0], r[1], r[2], r[5]) for r in gnss]
        wheels_csv = path / "can_wheel_speeds.csv"
        if wheels_csv.is_file():
            wheels, _, _ = read_table(wheels_csv, columns=5)
            dataset.wheel = [WheelOdometry(r[0], tuple(r[1:5]), float(r[1:5].mean())) for r in wheels]
        truth = path / "groundtruth_cam_optical_enu_tum.txt"
        if truth.is_file():
            dataset.ground_truth = read_trajectory(truth)
            dataset.ground_truth_note = "INS/GNSS post-processed camera pose (optical frame) in ENU"
        truth_ecef = path / "groundtruth_camera_ecef.csv"
        if truth_ecef.is_file():
            first, _, _ = read_table(truth_ecef, min_columns=6)
            dataset.enu_origin = tuple(float(v) for v in pymap3d.ecef2geodetic(*first[0, 3:6]))
        return dataset
