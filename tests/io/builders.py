"""Small, valid datasets of every format, built from the bundled sample's real frames.

Tests copy one, break one thing, and check that the reader names the problem precisely.
"""

from __future__ import annotations

import shutil
import struct
import zlib
from pathlib import Path

import cv2
import numpy as np
from PIL import Image
from PIL.TiffImagePlugin import IFDRational

from tests.conftest import SAMPLE

SAMPLE_CALIB = "335.419 335.353 129.925 99.186 -0.1386 0.0934 -0.0003 0.0002 0.0\n"


def sample_images(count: int = 5) -> list[Path]:
    return sorted((SAMPLE / "images").glob("*.png"))[:count]


def make_image_folder(root: Path, count: int = 5) -> Path:
    (root / "images").mkdir(parents=True)
    lines = []
    for i, src in enumerate(sample_images(count)):
        shutil.copy(src, root / "images" / src.name)
        lines.append(f"{i * 0.04:.6f} images/{src.name}")
    (root / "images.txt").write_text("\n".join(lines) + "\n")
    (root / "calib.txt").write_text(SAMPLE_CALIB)
    (root / "groundtruth.txt").write_text("".join(f"{i * 0.04} {i * 0.01} 0 0 0 0 0 1\n" for i in range(count)))
    return root


def make_euroc(root: Path, count: int = 5) -> Path:
    cam = root / "mav0" / "cam0"
    (cam / "data").mkdir(parents=True)
    rows = ["#timestamp [ns],filename"]
    for i, src in enumerate(sample_images(count)):
        stamp = 1_000_000_000_000 + i * 50_000_000
        shutil.copy(src, cam / "data" / f"{stamp}.png")
        rows.append(f"{stamp},{stamp}.png")
    (cam / "data.csv").write_text("\n".join(rows) + "\n")
    (cam / "sensor.yaml").write_text(
        "%YAML:1.0\nsensor_type: camera\nT_BS:\n  cols: 4\n  rows: 4\n  data: [1,0,0,0, 0,1,0,0, 0,0,1,0, 0,0,0,1]\n"
        "rate_hz: 20\nresolution: [240, 180]\ncamera_model: pinhole\nintrinsics: [335.4, 335.3, 129.9, 99.2]\n"
        "distortion_model: radial-tangential\ndistortion_coefficients: [-0.13, 0.09, 0.0, 0.0]\n"
    )
    imu = root / "mav0" / "imu0"
    imu.mkdir()
    imu_rows = ["#timestamp [ns],w_x,w_y,w_z,a_x,a_y,a_z"] + [f"{1_000_000_000_000 + i * 5_000_000},0,0,0.1,0,0,9.81" for i in range(40)]
    (imu / "data.csv").write_text("\n".join(imu_rows) + "\n")
    return root


def make_kitti(root: Path, count: int = 5) -> Path:
    (root / "image_0").mkdir(parents=True)
    for i, src in enumerate(sample_images(count)):
        shutil.copy(src, root / "image_0" / f"{i:06d}.png")
    (root / "times.txt").write_text("".join(f"{i * 0.1:e}\n" for i in range(count)))
    (root / "calib.txt").write_text("P0: 335.4 0 129.9 0 0 335.4 99.2 0 0 0 1 0\n")
    (root / "poses.txt").write_text("".join(f"1 0 0 0 0 1 0 0 0 0 1 {i * 1.0}\n" for i in range(count)))
    return root


def make_tum_rgbd(root: Path, count: int = 5) -> Path:
    (root / "rgb").mkdir(parents=True)
    lines = ["# color images", "# file: 'rgbd_dataset_freiburg1_xyz.bag'", "# timestamp filename"]
    for i, src in enumerate(sample_images(count)):
        shutil.copy(src, root / "rgb" / f"{1305031102.175304 + i * 0.033:.6f}.png")
        lines.append(f"{1305031102.175304 + i * 0.033:.6f} rgb/{1305031102.175304 + i * 0.033:.6f}.png")
    (root / "rgb.txt").write_text("\n".join(lines) + "\n")
    (root / "groundtruth.txt").write_text(
        "# timestamp tx ty tz qx qy qz qw\n" + "".join(f"{1305031102.17 + i * 0.01} {i * 0.001} 0 0 0 0 0 1\n" for i in range(20))
    )
    (root / "accelerometer.txt").write_text("# accelerometer data\n" + "".join(f"{1305031102.17 + i * 0.01} 0.1 -9.8 0.2\n" for i in range(20)))
    return root


def write_geotagged_jpeg(path: Path, seconds: int, lat: float, lon: float, alt: float, gps: bool = True) -> None:
    def dms(value: float):
        value = abs(value)
        d = int(value)
        m = int((value - d) * 60)
        s = (value - d - m / 60) * 3600
        return (IFDRational(d), IFDRational(m), IFDRational(round(s * 10000), 10000))

    image = Image.fromarray(cv2.cvtColor(cv2.imread(str(sample_images(1)[0])), cv2.COLOR_BGR2RGB))
    exif = Image.Exif()
    exif.get_ifd(0x8769).update({36867: f"2020:01:01 10:00:{seconds:02d}", 41989: 20})
    if gps:
        exif.get_ifd(0x8825).update(
            {1: "N" if lat >= 0 else "S", 2: dms(lat), 3: "E" if lon >= 0 else "W", 4: dms(lon), 5: b"\x00", 6: IFDRational(round(alt * 10), 10)}
        )
    image.save(path, exif=exif, quality=90)


def make_exif_photos(root: Path, count: int = 4) -> Path:
    root.mkdir(parents=True)
    for i in range(count):
        write_geotagged_jpeg(root / f"IMG_{i:04d}.jpg", 10 * i, 41.5486 + i * 1e-4, -83.6986, 120.0)
    return root


def make_video(root: Path, count: int = 12, fps: float = 10.0) -> Path:
    root.mkdir(parents=True, exist_ok=True)
    path = root / "flight.avi"
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), fps, (240, 180))
    for src in sample_images(count):
        writer.write(cv2.cvtColor(cv2.imread(str(src), cv2.IMREAD_GRAYSCALE), cv2.COLOR_GRAY2BGR))
    writer.release()
    return path


def noise_image(seed: int, shape=(48, 64)) -> np.ndarray:
    return np.random.default_rng(seed).integers(0, 255, shape, dtype=np.uint8)


def png_header_only(width: int, height: int) -> bytes:
    """A PNG's signature and IHDR chunk (what a header check reads), no image data."""
    ihdr = struct.pack(">IIBBBBB", width, height, 8, 0, 0, 0, 0)
    return b"\x89PNG\r\n\x1a\n" + struct.pack(">I", len(ihdr)) + b"IHDR" + ihdr + struct.pack(">I", zlib.crc32(b"IHDR" + ihdr))
