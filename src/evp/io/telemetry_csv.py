"""EVP telemetry CSV: every non-image sensor in one time-ordered file, one sample per row.

Rows are ``timestamp,sensor,values...`` with, per sensor:

=====  ===============================================================================
imu    wx wy wz (rad/s) ax ay az (m/s^2)
gps    latitude_deg longitude_deg altitude_m [horizontal_accuracy_m vertical_accuracy_m]
baro   pressure_pa [altitude_m]
wheel  forward_speed_m_s yaw_rate_rad_s wheel_speed_m_s...
wifi   bssid rssi_dbm [bssid rssi_dbm ...]
=====  ===============================================================================

A first line starting with ``timestamp`` is a header; ``#`` starts a comment line.
"""

from __future__ import annotations

import csv
import math
from collections.abc import Iterable
from pathlib import Path

from evp.errors import DatasetError
from evp.types import BaroSample, GpsFix, ImuSample, WheelOdometry, WifiScan

Record = ImuSample | GpsFix | BaroSample | WheelOdometry | WifiScan


def _floats(values: list[str]) -> list[float]:
    return [float(v) for v in values]


def _parse_row(sensor: str, t: float, values: list[str]) -> Record:
    if sensor == "imu":
        v = _floats(values)
        if len(v) != 6:
            raise ValueError(f"imu needs 6 values, found {len(v)}")
        return ImuSample(t, tuple(v[:3]), tuple(v[3:]))
    if sensor == "gps":
        v = _floats(values)
        if len(v) not in (3, 5):
            raise ValueError(f"gps needs 3 or 5 values, found {len(v)}")
        if not (-90 <= v[0] <= 90 and -180 <= v[1] <= 180):
            raise ValueError(f"latitude/longitude out of range: {v[0]}, {v[1]}")
        return GpsFix(t, *v)
    if sensor == "baro":
        v = _floats(values)
        if len(v) not in (1, 2):
            raise ValueError(f"baro needs 1 or 2 values, found {len(v)}")
        return BaroSample(t, *v)
    if sensor == "wheel":
        v = _floats(values)
        if len(v) < 2:
            raise ValueError(f"wheel needs at least 2 values, found {len(v)}")
        return WheelOdometry(t, tuple(v[2:]), v[0], v[1])
    if sensor == "wifi":
        if len(values) % 2:
            raise ValueError("wifi needs bssid,rssi pairs")
        return WifiScan(t, {values[i]: float(values[i + 1]) for i in range(0, len(values), 2)})
    raise ValueError(f"unknown sensor {sensor!r} (imu, gps, baro, wheel, wifi)")


def read_telemetry_csv(path: Path) -> list[Record]:
    """All records of a telemetry CSV, in file order (which must be time order)."""
    records: list[Record] = []
    last = -math.inf
    with path.open(newline="") as handle:
        for number, row in enumerate(csv.reader(handle), start=1):
            cells = [c.strip() for c in row if c.strip() != ""]
            if not cells or cells[0].startswith("#") or (number == 1 and cells[0].lower() == "timestamp"):
                continue
            if len(cells) < 2:
                raise DatasetError(path, "expected 'timestamp,sensor,values...'", line=number)
            try:
                t = float(cells[0])
                record = _parse_row(cells[1].lower(), t, cells[2:])
            except ValueError as exc:
                raise DatasetError(path, str(exc), line=number) from exc
            if t < last:
                raise DatasetError(path, f"timestamp {t} is earlier than the previous row's {last}", line=number)
            last = t
            records.append(record)
    return records


def _row(record: Record) -> list:
    if isinstance(record, ImuSample):
        return ["imu", *record.angular_velocity_rad_s, *record.linear_acceleration_m_s2]
    if isinstance(record, GpsFix):
        return ["gps", record.latitude_deg, record.longitude_deg, record.altitude_m, record.horizontal_accuracy_m, record.vertical_accuracy_m]
    if isinstance(record, BaroSample):
        return ["baro", record.pressure_pa, record.altitude_m]
    if isinstance(record, WheelOdometry):
        return ["wheel", record.forward_speed_m_s, record.yaw_rate_rad_s, *record.wheel_speeds_m_s]
    return ["wifi", *[x for item in record.rssi_dbm.items() for x in item]]


def write_telemetry_csv(path: Path, records: Iterable[Record]) -> None:
    with path.open("w", newline="") as handle:
        writer = csv.writer(handle)
        writer.writerow(["timestamp", "sensor", "values..."])
        for record in sorted(records, key=lambda r: r.timestamp):
            writer.writerow([repr(record.timestamp), *[repr(v) if isinstance(v, float) else v for v in _row(record)]])


def split_by_sensor(records: list[Record]) -> dict[str, list]:
    """Records grouped into the Dataset fields imu, gps, baro, wheel, wifi."""
    kinds = {ImuSample: "imu", GpsFix: "gps", BaroSample: "baro", WheelOdometry: "wheel", WifiScan: "wifi"}
    out: dict[str, list] = {name: [] for name in kinds.values()}
    for record in records:
        out[kinds[type(record)]].append(record)
    return out
