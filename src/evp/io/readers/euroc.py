"""EuRoC / ASL folders: ``mav0/cam0`` images, ``imu0``, ground truth, ``sensor.yaml`` calibration."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import yaml

from evp.calib.camera_files import load_yaml_mapping, read_camera
from evp.errors import DatasetError
from evp.io.dataset import Dataset, check_increasing, image_file_frames
from evp.io.text_tables import read_named_lines, read_table
from evp.io.trajectory import read_trajectory
from evp.types import BaroSample, GpsFix, ImuSample, RangeSample, Trajectory, WheelOdometry, WifiScan


def _mav0(path: Path) -> Path:
    return path if path.name == "mav0" else path / "mav0"


def _t_body_sensor(path: Path) -> np.ndarray:
    data = load_yaml_mapping(path, DatasetError)
    try:
        return np.asarray(data["T_BS"]["data"], dtype=float).reshape(4, 4)
    except (KeyError, TypeError, ValueError) as exc:
        raise DatasetError(path, f"cannot read T_BS extrinsics: {exc}") from exc


def _t_imu_cam(mav0: Path) -> np.ndarray | None:
    """cam0 in the imu0 frame from both sensors' ``T_BS`` (each relative to EuRoC's body frame,
    which is imu0's in EuRoC itself); None when either sensor.yaml is missing."""
    cam_yaml, imu_yaml = mav0 / "cam0" / "sensor.yaml", mav0 / "imu0" / "sensor.yaml"
    if not (cam_yaml.is_file() and imu_yaml.is_file()):
        return None
    return np.linalg.inv(_t_body_sensor(imu_yaml)) @ _t_body_sensor(cam_yaml)


def _stamped_images(folder: Path) -> list[Path]:
    """The PNGs of ``folder`` named by an integer nanosecond timestamp, in time order."""
    if not folder.is_dir():
        return []
    return sorted((p for p in folder.glob("*.png") if p.stem.isdigit()), key=lambda p: int(p.stem))


class EurocReader:
    name = "euroc"
    description = "EuRoC MAV / ASL folder (mav0/cam0/data.csv, sensor.yaml, imu0, state_groundtruth_estimate0)"
    looks_for = "mav0/cam0/data.csv, or mav0/cam0/data/ of images named by their nanosecond timestamps"

    def detect(self, path: Path) -> bool:
        cam_dir = _mav0(path) / "cam0"
        images = cam_dir / "data"
        return path.is_dir() and ((cam_dir / "data.csv").is_file() or (images.is_dir() and any(p.stem.isdigit() for p in images.glob("*.png"))))

    def read(self, path: Path) -> Dataset:
        mav0 = _mav0(path)
        root = mav0.parent
        cam_dir = mav0 / "cam0"
        if (cam_dir / "data.csv").is_file():
            stamps_ns, names, lines = read_named_lines(cam_dir / "data.csv")
            times = stamps_ns / 1e9
            check_increasing(cam_dir / "data.csv", times, "image", lines)
            paths = [cam_dir / "data" / name for name in names]
            missing = [p for p in paths if not p.is_file()]
            if missing:
                raise DatasetError(
                    cam_dir / "data.csv", f"{len(missing)} listed images are missing, first {missing[0].name}", line=lines[paths.index(missing[0])]
                )
            note = None
        else:
            paths = _stamped_images(cam_dir / "data")
            if not paths:
                raise DatasetError(cam_dir, "no data.csv and no images named by nanosecond timestamps in data/")
            times = np.array([int(p.stem) for p in paths]) / 1e9
            note = "no cam0/data.csv: frame times from the image names (nanoseconds, as EuRoC names them)"
        dataset = Dataset(root.name, self.name, root, read_camera(cam_dir / "sensor.yaml"), times, image_file_frames(times, paths))
        if note:
            dataset.notes.append(note)
        imu_csv = mav0 / "imu0" / "data.csv"
        if imu_csv.is_file():
            rows, _, _ = read_table(imu_csv, columns=7)
            dataset.imu = [ImuSample(t / 1e9, tuple(r[1:4]), tuple(r[4:7])) for t, r in zip(rows[:, 0], rows)]
            dataset.T_body_cam = _t_imu_cam(mav0)
        self._extra_sensors(mav0, dataset)
        self._ground_truth(mav0, root, dataset)
        self._geodetic_origin(root, dataset)
        leica = mav0 / "leica0" / "data.csv"
        if leica.is_file():
            rows, _, _ = read_table(leica, columns=4)
            quats = np.tile([0.0, 0.0, 0.0, 1.0], (len(rows), 1))
            dataset.trajectories["leica0_prism_positions"] = Trajectory(rows[:, 1:4], quats, rows[:, 0] / 1e9, "leica0")
        return dataset

    @staticmethod
    def _extra_sensors(mav0: Path, dataset: Dataset) -> None:
        """Sensors EuRoC lacks, in the same CSV style (written by ``evp sim``; see docs/simulator.md).
        A log with its header and no rows is a sensor that recorded nothing (a GPS jammed from
        take-off): read as empty, with a warning."""

        def rows_of(sensor: str, columns: int) -> np.ndarray | None:
            path = mav0 / sensor / "data.csv"
            if not path.is_file():
                return None
            rows, _, _ = read_table(path, columns=columns, allow_empty=True)
            if len(rows) == 0:
                dataset.warnings.append(f"{sensor}/data.csv has no rows: the {sensor[:-1]} recorded nothing")
            return rows

        if (rows := rows_of("gps0", 6)) is not None:
            dataset.gps = [GpsFix(r[0] / 1e9, *map(float, r[1:6])) for r in rows]
        if (rows := rows_of("baro0", 3)) is not None:
            dataset.baro = [BaroSample(r[0] / 1e9, float(r[1]), float(r[2])) for r in rows]
        if (rows := rows_of("range0", 2)) is not None:
            dataset.ranges = [RangeSample(r[0] / 1e9, float(r[1])) for r in rows]
        if (rows := rows_of("wheel0", 5)) is not None:
            dataset.wheel = [WheelOdometry(r[0] / 1e9, (float(r[1]), float(r[2])), float(r[3]), float(r[4])) for r in rows]
        if (mav0 / "wifi0" / "data.csv").is_file():
            dataset.wifi = read_wifi_csv(mav0 / "wifi0" / "data.csv")

    @staticmethod
    def _geodetic_origin(root: Path, dataset: Dataset) -> None:
        """``evp sim``'s world is ENU at the geodetic origin its sim.yaml records."""
        sim_yaml = root / "sim.yaml"
        if not sim_yaml.is_file():
            return
        origin = (yaml.safe_load(sim_yaml.read_text()) or {}).get("geodetic_origin")
        if origin:
            dataset.enu_origin = (float(origin["latitude_deg"]), float(origin["longitude_deg"]), float(origin["altitude_m"]))

    def _ground_truth(self, mav0: Path, root: Path, dataset: Dataset) -> None:
        """Camera GT: body GT times cam0 extrinsics when the standard CSV exists, else a cam0 TUM file."""
        body_csv = mav0 / "state_groundtruth_estimate0" / "data.csv"
        if body_csv.is_file():
            body = read_trajectory(body_csv)
            t_body_cam = _t_body_sensor(mav0 / "cam0" / "sensor.yaml")
            dataset.ground_truth = Trajectory.from_poses(body.poses @ t_body_cam, body.timestamps, "groundtruth_cam0")
            dataset.ground_truth_note = "state_groundtruth_estimate0 (body) x cam0 T_BS: T_world_cam0"
            return
        candidates = sorted(p for p in root.glob("groundtruth*cam0*.txt") if "full" not in p.name)
        if candidates:
            dataset.ground_truth = read_trajectory(candidates[0])
            dataset.ground_truth_note = f"{candidates[0].name}: T_world_cam0"


def read_wifi_csv(path: Path) -> list[WifiScan]:
    """``timestamp_ns,bssid,rssi`` rows, grouped into one scan per timestamp."""
    scans: dict[int, dict[str, float]] = {}
    for number, line in enumerate(path.read_text().splitlines(), start=1):
        if not line.strip() or line.startswith("#"):
            continue
        fields = line.split(",")
        try:
            stamp, bssid, rssi = int(fields[0]), fields[1].strip(), float(fields[2])
        except (ValueError, IndexError) as exc:
            raise DatasetError(path, f"expected 'timestamp_ns,bssid,rssi': {exc}", line=number) from exc
        scans.setdefault(stamp, {})[bssid] = rssi
    return [WifiScan(stamp / 1e9, rssi) for stamp, rssi in sorted(scans.items())]
