"""What every dataset reader returns: frames, telemetry, calibration and ground truth."""

from __future__ import annotations

import heapq
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from evp.errors import DatasetError
from evp.io.image_headers import read_image_header
from evp.types import BaroSample, BeaconRange, CameraModel, EncoderCounts, Frame, GpsFix, ImuSample, RangeSample, Trajectory, WheelOdometry, WifiScan

# what runs the camera-less recordings (wheel odometry, beacon ranges, GNSS): the filter against
# odometry alone on the shared datasets, as issue 30 measured it
CAMERALESS_BENCH = "python bench/ground_vehicles.py"

SENSOR_NAMES = {
    "camera": "camera frames",
    "imu": "IMU",
    "gps": "GNSS fixes",
    "baro": "barometer",
    "wheel": "wheel odometry",
    "wifi": "WiFi scans",
    "range": "range finder",
    "beacon": "beacon ranges",
}

TelemetryRecord = ImuSample | GpsFix | BaroSample | WheelOdometry | EncoderCounts | WifiScan | RangeSample | BeaconRange


@dataclass
class Dataset:
    """A recorded sequence.

    Images are loaded lazily by :meth:`frames`; everything else is held in memory. ``frame_times``
    lists every frame's timestamp (seconds) so that summaries need not decode images.
    """

    name: str
    format: str
    root: Path
    camera: CameraModel | None = None
    frame_times: np.ndarray = field(default_factory=lambda: np.zeros(0))
    load_frames: Callable[[list[DatasetError] | None], Iterator[Frame]] | None = None
    imu: list[ImuSample] = field(default_factory=list)
    gps: list[GpsFix] = field(default_factory=list)
    baro: list[BaroSample] = field(default_factory=list)
    wheel: list[WheelOdometry] = field(default_factory=list)
    wifi: list[WifiScan] = field(default_factory=list)
    ranges: list[RangeSample] = field(default_factory=list)
    beacons: dict[str, tuple[float, float, float]] = field(default_factory=dict)  # surveyed position (m) per beacon id, in the ground truth's frame
    beacon_ranges: list[BeaconRange] = field(default_factory=list)
    ground_truth: Trajectory | None = None
    ground_truth_note: str = ""
    ground_truth_orientation: bool = True  # False: the ground truth measures positions only (GPS, 2-D tracks); its quaternions are placeholders
    enu_origin: tuple[float, float, float] | None = None  # WGS-84 latitude, longitude (deg), altitude (m) of the ground truth's ENU frame, when georeferenced
    trajectories: dict[str, Trajectory] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)  # what the reader had to assume (nominal frame times...): commands print them
    T_body_cam: np.ndarray | None = None  # the camera in the IMU frame (4x4, metres), when the dataset calibrates it

    @property
    def num_frames(self) -> int:
        return len(self.frame_times)

    def frames(self, errors: list[DatasetError] | None = None) -> Iterator[Frame]:
        """Frames in time order, images decoded one at a time.

        An undecodable image raises :class:`DatasetError`, unless ``errors`` is a list: then the
        frame is skipped and its error appended there (a long run loses one frame, not all).
        """
        if self.load_frames is None:
            return iter(())
        return self.load_frames(errors)

    def telemetry(self) -> Iterator[TelemetryRecord]:
        """All non-image samples merged in time order."""
        streams = [self.imu, self.gps, self.baro, self.wheel, self.wifi, self.ranges, self.beacon_ranges]
        return heapq.merge(*streams, key=lambda record: record.timestamp)

    def stream(self) -> Iterator[Frame | TelemetryRecord]:
        """Frames and telemetry merged in time order (what a live source would deliver)."""
        return heapq.merge(self.frames(), self.telemetry(), key=lambda record: record.timestamp)

    def sensors(self) -> dict[str, int]:
        """Sample count per sensor present."""
        counts = {
            "camera": self.num_frames,
            "imu": len(self.imu),
            "gps": len(self.gps),
            "baro": len(self.baro),
            "wheel": len(self.wheel),
            "wifi": len(self.wifi),
            "range": len(self.ranges),
            "beacon": len(self.beacon_ranges),
        }
        return {name: count for name, count in counts.items() if count}

    def ground_truth_excursion(self) -> float | None:
        """How far (m) the ground truth gets from where it was at the first frame while the frames
        run: what tells a camera that stood still (EuRoC V1_01's first seconds: 2 mm) from one
        the estimator failed on; None without timed ground truth over the frames."""
        truth = self.ground_truth
        if truth is None or truth.timestamps is None or self.num_frames == 0:
            return None
        during = (truth.timestamps >= self.frame_times[0]) & (truth.timestamps <= self.frame_times[-1])
        if not during.any():
            return None
        positions = truth.positions[during]
        return float(np.linalg.norm(positions - positions[0], axis=1).max())

    def no_frames_reason(self) -> str:
        """Why ``evp run`` cannot run here, for a recording without images (comma2k19's segment,
        the wheel robots, trajectory files): what it holds instead, and what puts that to use."""
        if not self.sensors():
            return "no camera frames to run on: only trajectories here; compare two with evp eval REF EST"
        held = ", ".join(SENSOR_NAMES[name] for name in self.sensors()) + (" and ground truth" if self.ground_truth is not None else "")
        reason = f"no camera frames to run on: this {self.format} recording holds {held} (evp info lists them), and evp run estimates from a camera"
        if self.wheel or self.beacon_ranges:
            reason += f"; its wheel odometry{' and beacon ranges' if self.beacon_ranges else ''} without images run in {CAMERALESS_BENCH}"
        return reason


# The largest image decoded: 134 Mpx (2^27; 400 MB as BGR), beyond any camera a dataset holds
# (a 108 Mpx phone photo fits); a 20000x20000 PNG of a few kilobytes would cost 1.2 GB to decode.
MAX_DECODE_PIXELS = 2**27


def load_image(path: Path) -> np.ndarray:
    """Decode an image file as stored (grey stays grey), naming the file when it is unreadable; an
    image too large to decode (MAX_DECODE_PIXELS) is refused from its header, before decoding."""
    data = np.fromfile(str(path), dtype=np.uint8) if path.is_file() else None
    if data is None:
        raise DatasetError(path, "image file is missing")
    header = read_image_header(data[:65536].tobytes())
    if header is not None and header.width * header.height > MAX_DECODE_PIXELS:
        raise DatasetError(path, f"{header.format} of {header.width}x{header.height} pixels: more than {MAX_DECODE_PIXELS / 1e6:.0f} Mpx, not decoded")
    image = cv2.imdecode(data, cv2.IMREAD_UNCHANGED) if data.size else None
    if image is None:
        raise DatasetError(path, "image cannot be decoded (empty or corrupt file)")
    if image.dtype != np.uint8:
        image = cv2.convertScaleAbs(image, alpha=255.0 / max(1.0, float(image.max())))
    if image.ndim == 3 and image.shape[2] == 4:
        image = cv2.cvtColor(image, cv2.COLOR_BGRA2BGR)
    return image


def image_file_frames(times: np.ndarray, paths: list[Path]) -> Callable[[], Iterator[Frame]]:
    """A frame loader over image files with known timestamps."""

    def load(errors: list[DatasetError] | None = None) -> Iterator[Frame]:
        for index, (stamp, path) in enumerate(zip(times, paths)):
            try:
                image = load_image(path)
            except DatasetError as exc:
                if errors is None:
                    raise
                errors.append(exc)
                continue
            yield Frame(float(stamp), image, index, str(path))

    return load


def check_increasing(path: Path, stamps: np.ndarray, what: str, line_numbers: list[int] | None = None) -> None:
    """Raise naming the first line whose timestamp is not a finite number or does not increase
    (``line_numbers[i]`` is row i's line)."""
    not_finite = np.flatnonzero(~np.isfinite(stamps))
    if len(not_finite):
        row = int(not_finite[0])
        line = line_numbers[row] if line_numbers is not None else row + 1
        raise DatasetError(path, f"{what} timestamp {float(stamps[row])!r} is not a finite number ({len(not_finite)} of {len(stamps)} such)", line=line)
    bad = np.flatnonzero(np.diff(stamps) <= 0)
    if len(bad):
        row = int(bad[0]) + 1
        line = line_numbers[row] if line_numbers is not None else row + 1
        raise DatasetError(path, f"{what} timestamps must increase ({float(stamps[row])!r} after {float(stamps[row - 1])!r})", line=line)


def image_size(path: Path) -> tuple[int, int]:
    """(width, height) of an image file."""
    image = load_image(path)
    return image.shape[1], image.shape[0]
