"""Read camera calibration from the files robotics tools write, and write OpenCV FileStorage YAML.

Understood formats (detected from the keys):

* OpenCV FileStorage (``camera_matrix``, ``distortion_coefficients``, ``image_width/height``),
  as written by ``evp calibrate`` and OpenCV's calibration sample
* ROS ``camera_info`` YAML (``camera_matrix: {rows, cols, data}``, ``distortion_model``)
* ORB-SLAM2/3 settings (``Camera.fx`` ... or ``Camera1.fx`` ..., ``Camera.width``)
* Kalibr camchain (``cam0: {intrinsics, distortion_coeffs, resolution}``) and EuRoC ``sensor.yaml``
* one line of numbers ``fx fy cx cy [k1 k2 p1 p2 [k3]]`` (RPG / DAVIS style ``calib.txt``)
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import cv2
import numpy as np
import yaml

from evp.errors import CalibrationError
from evp.types import CameraModel


def _camera(path: Path, width, height, fx, fy, cx, cy, dist, name: str) -> CameraModel:
    dist = [float(d) for d in (list(dist) + [0.0] * 5)[:5]]
    try:
        return CameraModel(int(width), int(height), float(fx), float(fy), float(cx), float(cy), *dist, name=name)
    except (TypeError, ValueError) as exc:
        raise CalibrationError(path, f"invalid camera parameters: {exc}") from exc


def load_yaml_mapping(path: Path, error=CalibrationError) -> dict[str, Any]:
    """A YAML mapping, also from OpenCV FileStorage files (``%YAML:1.0`` header, ``!!opencv-matrix`` tags)."""
    try:
        text = path.read_text()
    except (OSError, UnicodeDecodeError) as exc:
        raise error(path, f"cannot be read: {exc}") from exc
    lines = text.splitlines()
    total = len(lines)
    if lines and lines[0].startswith("%YAML"):
        lines = lines[1:]
        if lines and lines[0].strip() == "---":
            lines = lines[1:]
    text = "\n".join(lines).replace("!!opencv-matrix", "")
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        line = None if mark is None else mark.line + 1 + total - len(lines)
        raise error(path, f"invalid YAML: {getattr(exc, 'problem', exc)}", line=line) from exc
    if not isinstance(data, dict):
        raise error(path, "expected a YAML mapping")
    return data


def _matrix(value: Any) -> np.ndarray:
    if isinstance(value, dict) and "data" in value:
        return np.asarray(value["data"], dtype=float)
    return np.asarray(value, dtype=float).ravel()


def _from_opencv(path: Path, data: dict) -> CameraModel:
    K = _matrix(data["camera_matrix"]).reshape(3, 3)
    dist = _matrix(data.get("distortion_coefficients", np.zeros(5)))
    width = data.get("image_width")
    height = data.get("image_height")
    if width is None or height is None:
        raise CalibrationError(path, "image_width and image_height are required")
    model = str(data.get("distortion_model", "plumb_bob"))
    if model not in ("plumb_bob", "radtan", "radial-tangential", "rational_polynomial") or len(dist) > 8:
        raise CalibrationError(path, f"unsupported distortion model {model!r} (EVP uses OpenCV radial-tangential)")
    return _camera(path, width, height, K[0, 0], K[1, 1], K[0, 2], K[1, 2], dist, str(data.get("camera_name", path.stem)))


def _from_orbslam(path: Path, data: dict) -> CameraModel:
    prefix = "Camera1." if "Camera1.fx" in data else "Camera."
    get = lambda key, default=None: data.get(prefix + key, data.get("Camera." + key, default))  # noqa: E731
    width = get("width", data.get("Camera.width"))
    height = get("height", data.get("Camera.height"))
    if width is None or height is None:
        raise CalibrationError(path, "ORB-SLAM settings need Camera.width and Camera.height")
    dist = [get(k, 0.0) for k in ("k1", "k2", "p1", "p2", "k3")]
    return _camera(path, width, height, get("fx"), get("fy"), get("cx"), get("cy"), dist, path.stem)


def _from_kalibr(path: Path, cam: dict, name: str) -> CameraModel:
    model = cam.get("camera_model", "pinhole")
    distortion = cam.get("distortion_model", "radtan")
    if model != "pinhole" or distortion not in ("radtan", "radial-tangential"):
        raise CalibrationError(path, f"unsupported camera/distortion model {model}/{distortion} (EVP uses pinhole + radtan)")
    fx, fy, cx, cy = cam["intrinsics"]
    coeffs = cam.get("distortion_coeffs", cam.get("distortion_coefficients", []))
    width, height = cam["resolution"]
    return _camera(path, width, height, fx, fy, cx, cy, coeffs, name)


def _from_numbers(path: Path, text: str, width: int | None, height: int | None) -> CameraModel:
    try:
        values = [float(v) for v in text.split()]
    except ValueError as exc:
        raise CalibrationError(path, f"expected numbers 'fx fy cx cy [k1 k2 p1 p2 [k3]]': {exc}", line=1) from exc
    if len(values) not in (4, 8, 9):
        raise CalibrationError(path, f"expected 4, 8 or 9 numbers (fx fy cx cy k1 k2 p1 p2 k3), found {len(values)}", line=1)
    if width is None or height is None:
        raise CalibrationError(path, "this calibration has no image size; it is taken from the images")
    return _camera(path, width, height, *values[:4], values[4:], path.stem)


def read_camera(path: str | Path, width: int | None = None, height: int | None = None, camera: str = "cam0") -> CameraModel:
    """Read a camera model from any supported calibration file.

    ``width``/``height`` are needed only for files that do not store the resolution (plain numbers).
    ``camera`` picks the camera in a multi-camera Kalibr camchain.
    """
    path = Path(path)
    if not path.is_file():
        raise CalibrationError(path, "calibration file not found")
    if path.suffix.lower() == ".txt":
        lines = [line for line in path.read_text().splitlines() if line.strip() and not line.lstrip().startswith("#")]
        if not lines:
            raise CalibrationError(path, "empty calibration file")
        return _from_numbers(path, lines[0], width, height)
    data = load_yaml_mapping(path)
    try:
        if "camera_matrix" in data:
            return _from_opencv(path, data)
        if "Camera.fx" in data or "Camera1.fx" in data:
            return _from_orbslam(path, data)
        if camera in data and isinstance(data[camera], dict):
            return _from_kalibr(path, data[camera], camera)
        if "intrinsics" in data and "resolution" in data:
            return _from_kalibr(path, data, path.parent.name or path.stem)
    except KeyError as exc:
        raise CalibrationError(path, f"missing key {exc.args[0]!r}") from exc
    except (TypeError, ValueError) as exc:
        raise CalibrationError(path, f"malformed calibration values: {exc}") from exc
    raise CalibrationError(path, "not a calibration file EVP understands (OpenCV, ROS camera_info, ORB-SLAM, Kalibr or EuRoC sensor.yaml)")


def write_opencv_yaml(path: str | Path, camera: CameraModel, extra: dict[str, float | int] | None = None, text: dict[str, str] | None = None) -> None:
    """OpenCV FileStorage YAML, readable by OpenCV, ORB-SLAM-style tools and :func:`read_camera`."""
    storage = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    storage.write("camera_name", camera.name or "camera")
    storage.write("image_width", camera.width)
    storage.write("image_height", camera.height)
    storage.write("camera_matrix", camera.K)
    storage.write("distortion_model", "plumb_bob")
    storage.write("distortion_coefficients", camera.distortion.reshape(1, 5))
    for key, value in (extra or {}).items():
        storage.write(key, value if isinstance(value, int) else float(value))
    for key, value in (text or {}).items():
        storage.write(key, str(value))
    storage.release()
