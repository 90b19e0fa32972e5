"""Photo folders whose JPEGs carry EXIF GPS (drone surveys): frames, GPS fixes and ENU positions.

Times are seconds since the first photo (EXIF ``DateTimeOriginal``, 1 s resolution, camera clock;
``SubSecTimeOriginal`` is used when present). Ground truth is the GPS position in a local ENU frame
at the first fix (position only: orientation is not measured). Intrinsics come from a
``camera.yaml`` beside the photos or, failing that, the nominal EXIF focal length.
"""

from __future__ import annotations

import math
from datetime import datetime
from pathlib import Path

import numpy as np
import pymap3d
from PIL import Image, UnidentifiedImageError

from evp.calib.camera_files import read_camera
from evp.errors import DatasetError
from evp.io.dataset import Dataset, image_file_frames
from evp.types import CameraModel, GpsFix, Trajectory

GPS_IFD = 0x8825
EXIF_IFD = 0x8769
DATETIME_ORIGINAL = 36867
SUBSEC_ORIGINAL = 37521
FOCAL_LENGTH = 37386
FOCAL_35MM = 41989
JPEG_SUFFIXES = {".jpg", ".jpeg"}
FULL_FRAME_DIAGONAL_MM = math.hypot(36.0, 24.0)


def _photo_dir(path: Path) -> Path:
    return path / "images" if (path / "images").is_dir() else path


def _degrees(dms, ref: str) -> float:
    value = float(dms[0]) + float(dms[1]) / 60.0 + float(dms[2]) / 3600.0
    return -value if ref in ("S", "W") else value


def read_photo_exif(path: Path) -> tuple[float, GpsFix, tuple[int, int], float | None]:
    """(POSIX time of capture, GPS fix, (width, height), 35 mm equivalent focal length) of one photo."""
    try:
        with Image.open(path) as image:
            size = image.size
            exif = image.getexif()
    except (OSError, UnidentifiedImageError) as exc:
        raise DatasetError(path, f"cannot read image header: {exc}") from exc
    gps = exif.get_ifd(GPS_IFD)
    details = exif.get_ifd(EXIF_IFD)
    if not gps or 2 not in gps or 4 not in gps:
        raise DatasetError(path, "no EXIF GPS position", record="GPSInfo")
    stamp_text = details.get(DATETIME_ORIGINAL) or exif.get(306)
    if not stamp_text:
        raise DatasetError(path, "no EXIF capture time", record="DateTimeOriginal")
    try:
        stamp = datetime.strptime(str(stamp_text).strip("\x00 "), "%Y:%m:%d %H:%M:%S").timestamp()
        lat = _degrees(gps[2], str(gps.get(1, "N")).strip("\x00"))
        lon = _degrees(gps[4], str(gps.get(3, "E")).strip("\x00"))
        alt = float(gps.get(6, float("nan")))
    except (ValueError, TypeError, ZeroDivisionError) as exc:
        raise DatasetError(path, f"malformed EXIF GPS or time: {exc}", record="GPSInfo") from exc
    if gps.get(5) in (1, b"\x01"):
        alt = -alt
    subsec = str(details.get(SUBSEC_ORIGINAL, "")).strip("\x00 ")
    if subsec.isdigit():
        stamp += float("0." + subsec)
    focal_35 = details.get(FOCAL_35MM)
    return stamp, GpsFix(stamp, lat, lon, alt), size, float(focal_35) if focal_35 else None


def nominal_camera(width: int, height: int, focal_35mm: float) -> CameraModel:
    """Pinhole from the 35 mm equivalent focal length (defined on the image diagonal)."""
    f = focal_35mm / FULL_FRAME_DIAGONAL_MM * math.hypot(width, height)
    return CameraModel(width, height, f, f, (width - 1) / 2.0, (height - 1) / 2.0, name="exif_nominal")


class ExifPhotoReader:
    name = "exif-photos"
    description = "folder of JPEG photos with EXIF GPS (drone survey); GPS as ENU ground truth"
    looks_for = "JPEG photos (here or in images/) whose first carries EXIF GPS"

    def detect(self, path: Path) -> bool:
        if not path.is_dir():
            return False
        photos = sorted(p for p in _photo_dir(path).iterdir() if p.suffix.lower() in JPEG_SUFFIXES)
        if not photos:
            return False
        try:
            with Image.open(photos[0]) as image:
                return bool(image.getexif().get_ifd(GPS_IFD))
        except (OSError, UnidentifiedImageError):
            return False

    def read(self, path: Path) -> Dataset:
        photos = sorted(p for p in _photo_dir(path).iterdir() if p.suffix.lower() in JPEG_SUFFIXES)
        records = sorted((read_photo_exif(p) + (p,) for p in photos), key=lambda r: (r[0], r[4].name))
        t0 = records[0][0]
        times = np.array([r[0] - t0 for r in records])
        fixes = [GpsFix(r[1].timestamp - t0, r[1].latitude_deg, r[1].longitude_deg, r[1].altitude_m) for r in records]
        width, height = records[0][2]
        if (path / "camera.yaml").is_file():
            camera, note = read_camera(path / "camera.yaml"), "camera.yaml"
        elif records[0][3]:
            camera, note = nominal_camera(width, height, records[0][3]), "nominal from EXIF 35 mm focal length (uncalibrated)"
        else:
            raise DatasetError(records[0][4], "no camera.yaml and no EXIF FocalLengthIn35mmFilm to derive intrinsics")
        dataset = Dataset(path.name, self.name, path, camera, times, image_file_frames(times, [r[4] for r in records]))
        dataset.gps = fixes
        dataset.notes.append(f"calibration: {note}")
        dataset.notes.append(f"times: seconds since the first photo ({datetime.fromtimestamp(t0):%Y-%m-%d %H:%M:%S} camera clock)")
        origin = fixes[0]
        east, north, up = pymap3d.geodetic2enu(
            np.array([f.latitude_deg for f in fixes]),
            np.array([f.longitude_deg for f in fixes]),
            np.array([f.altitude_m for f in fixes]),
            origin.latitude_deg,
            origin.longitude_deg,
            origin.altitude_m,
        )
        quats = np.tile([0.0, 0.0, 0.0, 1.0], (len(fixes), 1))
        dataset.ground_truth = Trajectory(np.column_stack([east, north, up]), quats, times, "gps_enu")
        dataset.ground_truth_orientation = False
        dataset.ground_truth_note = (
            f"EXIF GPS in ENU at the first fix ({origin.latitude_deg:.6f}, {origin.longitude_deg:.6f}, {origin.altitude_m:.1f} m); position only"
        )
        return dataset
