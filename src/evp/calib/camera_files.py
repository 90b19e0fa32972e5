"""Read camera calibration from the files robotics tools write, and write OpenCV FileStorage YAML.

Understood formats (detected from the keys), and the lens models each can state
(:class:`evp.types.LensModel`: pinhole radial-tangential with OpenCV's 4, 5 or 8 coefficients,
or the equidistant Kannala-Brandt fisheye):

* OpenCV FileStorage (``camera_matrix``, ``distortion_coefficients``, ``image_width/height``), as
  written by ``evp calibrate`` and OpenCV's calibration sample: radtan from 4, 5 or 8
  coefficients; equidistant when ``distortion_model`` says so or the sample's ``fisheye_model``
  flag is set
* ROS ``camera_info`` YAML (``camera_matrix: {rows, cols, data}``, ``distortion_model``):
  ``plumb_bob``, ``rational_polynomial``, ``equidistant``
* ORB-SLAM2/3 settings (``Camera.fx`` ... or ``Camera1.fx`` ..., ``Camera.width``):
  ``Camera.type`` ``PinHole``, ``KannalaBrandt8`` or ``Rectified`` (ORB-SLAM2: no type, pinhole)
* Kalibr camchain (``cam0: {intrinsics, distortion_coeffs, resolution}``) and EuRoC
  ``sensor.yaml``: ``pinhole`` with ``radtan`` (``radial-tangential``), ``equidistant`` or ``none``
* one line of numbers ``fx fy cx cy [k1 k2 p1 p2 [k3]]`` (RPG / DAVIS style ``calib.txt``) and
  KITTI's ``calib.txt`` (``P0: ...`` projection lines, camera 0 read): both without the image size,
  which the caller gives (a dataset's images, or ``evp camera --width --height``)

A lens model EVP cannot use (OpenCV's thin-prism and tilted-sensor terms, Kalibr's omni, double
sphere, extended unified and FOV models, an unknown ORB-SLAM camera type) is refused by name with
a :class:`~evp.errors.CalibrationError`, never read as another model.
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import yaml

from evp.errors import CalibrationError
from evp.types import CameraModel, LensModel

RADTAN_NAMES = ("plumb_bob", "rational_polynomial", "radtan", "radial-tangential")  # ROS, Kalibr, EuRoC
EQUIDISTANT_NAMES = ("equidistant", "fisheye")  # ROS and Kalibr; "fisheye" as some OpenCV tools write it
# OpenCV coefficient counts beyond the rational model, and the terms they add
OPENCV_REFUSED_COUNTS = {12: "thin-prism model (s1..s4)", 14: "tilted-sensor model (s1..s4, tauX, tauY)"}
KALIBR_REFUSED = {
    "omni": "unified omnidirectional (Mei)",
    "ds": "double sphere",
    "eucm": "extended unified (EUCM)",
    "fov": "field-of-view (Devernay-Faugeras)",
}
ORBSLAM_TYPES = ("PinHole", "KannalaBrandt8", "Rectified")


def _camera(path: Path, width, height, fx, fy, cx, cy, coefficients: Sequence, lens: LensModel, name: str) -> CameraModel:
    """The camera from OpenCV-ordered coefficients of its lens model: radtan k1 k2 p1 p2 [k3 [k4 k5
    k6]] (none, 4, 5 or 8), equidistant k1 k2 k3 k4."""
    values = [float(c) for c in coefficients]
    count = len(values)
    if count in OPENCV_REFUSED_COUNTS:
        raise CalibrationError(
            path,
            f"{count} distortion coefficients: OpenCV's {OPENCV_REFUSED_COUNTS[count]} is not supported (EVP uses 4, 5 or 8 radial-tangential or 4 equidistant)",
        )
    if lens is LensModel.EQUIDISTANT:
        if count != 4:
            raise CalibrationError(path, f"an equidistant (fisheye) lens has 4 coefficients k1..k4, found {count}")
        names = ("k1", "k2", "k3", "k4")
    else:
        if count not in (0, 4, 5, 8):
            raise CalibrationError(path, f"a radial-tangential lens has 4, 5 or 8 coefficients (k1 k2 p1 p2 [k3 [k4 k5 k6]]), found {count}")
        names = ("k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6")[:count]
    try:
        return CameraModel(int(width), int(height), float(fx), float(fy), float(cx), float(cy), name=name, lens=lens, **dict(zip(names, values, strict=True)))
    except (TypeError, ValueError) as exc:
        raise CalibrationError(path, f"invalid camera parameters: {exc}") from exc


def lens_from_ros(path: Path, model: str | None, count: int) -> LensModel:
    """The lens of a ROS / OpenCV ``distortion_model`` name (None when the file names none: then
    radial-tangential, OpenCV's pinhole convention for 4, 5 or 8 coefficients)."""
    if model is None or model in RADTAN_NAMES:
        if model == "rational_polynomial" and count != 8:
            raise CalibrationError(path, f"rational_polynomial has 8 coefficients (k1 k2 p1 p2 k3 k4 k5 k6), found {count}")
        return LensModel.RADTAN
    if model in EQUIDISTANT_NAMES:
        return LensModel.EQUIDISTANT
    raise CalibrationError(path, f"unsupported distortion model {model!r} (EVP uses plumb_bob, rational_polynomial or equidistant)")


def camera_from_ros(path: Path, width, height, K: np.ndarray, model: str | None, coefficients: Sequence, name: str) -> CameraModel:
    """A camera from a ROS ``CameraInfo`` (or OpenCV FileStorage) intrinsic matrix, distortion model
    name and coefficients; ``path`` names the file it came from in errors."""
    K = np.asarray(K, dtype=float).reshape(3, 3)
    coefficients = list(np.asarray(coefficients, dtype=float).ravel())
    lens = lens_from_ros(path, model, len(coefficients))
    return _camera(path, width, height, K[0, 0], K[1, 1], K[0, 2], K[1, 2], coefficients, lens, name)


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
    """OpenCV FileStorage or ROS camera_info YAML."""
    width = data.get("image_width")
    height = data.get("image_height")
    if width is None or height is None:
        raise CalibrationError(path, "image_width and image_height are required")
    model = data.get("distortion_model")
    if model is None and data.get("fisheye_model"):  # OpenCV's calibration sample run with its fisheye option
        model = "equidistant"
    dist = _matrix(data.get("distortion_coefficients", np.zeros(0)))
    name = str(data.get("camera_name", path.stem))
    return camera_from_ros(path, width, height, _matrix(data["camera_matrix"]), None if model is None else str(model), dist, name)


def _from_orbslam(path: Path, data: dict) -> CameraModel:
    """ORB-SLAM3 settings name the model in ``Camera.type``; ORB-SLAM2's (no type) are pinhole."""
    prefix = "Camera1." if "Camera1.fx" in data else "Camera."
    get = lambda key, default=None: data.get(prefix + key, data.get("Camera." + key, default))  # noqa: E731
    width = get("width", data.get("Camera.width"))
    height = get("height", data.get("Camera.height"))
    if width is None or height is None:
        raise CalibrationError(path, "ORB-SLAM settings need Camera.width and Camera.height")
    kind = str(data.get("Camera.type", "PinHole"))
    if kind not in ORBSLAM_TYPES:
        raise CalibrationError(path, f"ORB-SLAM camera type {kind!r} is not supported (EVP reads {', '.join(ORBSLAM_TYPES)})")
    if kind == "KannalaBrandt8":
        lens, names = LensModel.EQUIDISTANT, ("k1", "k2", "k3", "k4")
    elif kind == "Rectified":  # images already undistorted: ORB-SLAM3 ignores any coefficients given
        lens, names = LensModel.RADTAN, ()
    else:
        lens, names = LensModel.RADTAN, ("k1", "k2", "p1", "p2") + (("k3",) if get("k3") is not None else ())
    coefficients = [get(name, 0.0) for name in names]
    return _camera(path, width, height, get("fx"), get("fy"), get("cx"), get("cy"), coefficients, lens, path.stem)


def _from_kalibr(path: Path, cam: dict, name: str) -> CameraModel:
    model = str(cam.get("camera_model", "pinhole"))
    distortion = str(cam.get("distortion_model", "radtan"))
    for kind, part in ((model, "camera model"), (distortion, "distortion model")):
        if kind in KALIBR_REFUSED:
            raise CalibrationError(path, f"Kalibr {part} {kind!r} ({KALIBR_REFUSED[kind]}) is not supported (EVP uses pinhole with radtan or equidistant)")
    if model != "pinhole" or distortion not in ("radtan", "radial-tangential", "equidistant", "none"):
        raise CalibrationError(path, f"unsupported camera/distortion model {model}/{distortion} (EVP uses pinhole with radtan or equidistant)")
    lens = LensModel.EQUIDISTANT if distortion == "equidistant" else LensModel.RADTAN
    fx, fy, cx, cy = cam["intrinsics"]
    coefficients = [] if distortion == "none" else cam.get("distortion_coeffs", cam.get("distortion_coefficients", []))
    width, height = cam["resolution"]
    return _camera(path, width, height, fx, fy, cx, cy, coefficients, lens, name)


PROJECTION_LINE = re.compile(r"^\s*P\d\s*:")


def is_kitti_calib(path: Path) -> bool:
    """Whether a ``calib.txt`` holds KITTI projection lines (``P0: ...``) rather than plain numbers."""
    try:
        lines = [line for line in path.read_text().splitlines() if line.strip()]
    except (OSError, UnicodeDecodeError):
        return False
    return bool(lines) and PROJECTION_LINE.match(lines[0]) is not None


def read_kitti_projection(path: Path, camera: int = 0) -> np.ndarray:
    """The 3x4 ``P<camera>`` matrix of a KITTI ``calib.txt`` (rectified, in camera 0's frame)."""
    if not path.is_file():
        raise CalibrationError(path, "calib.txt not found")
    key = f"P{camera}:"
    for number, line in enumerate(path.read_text().splitlines(), start=1):
        if line.startswith(key):
            try:
                return np.array([float(v) for v in line.split()[1:]]).reshape(3, 4)
            except ValueError as exc:
                raise CalibrationError(path, f"P{camera} must hold 12 numbers: {exc}", line=number) from exc
    raise CalibrationError(path, f"no '{key}' line")


def kitti_camera(P: np.ndarray, width: int, height: int, camera: int = 0) -> CameraModel:
    """The pinhole of a rectified KITTI camera from its projection ``P = K [I | t]`` (no distortion)."""
    return CameraModel(width, height, float(P[0, 0]), float(P[1, 1]), float(P[0, 2]), float(P[1, 2]), name=f"kitti_cam{camera}")


def _from_numbers(path: Path, text: str, width: int | None, height: int | None) -> CameraModel:
    try:
        values = [float(v) for v in text.split()]
    except ValueError as exc:
        raise CalibrationError(path, f"expected numbers 'fx fy cx cy [k1 k2 p1 p2 [k3]]': {exc}", line=1) from exc
    if len(values) not in (4, 8, 9):
        raise CalibrationError(path, f"expected 4, 8 or 9 numbers (fx fy cx cy k1 k2 p1 p2 k3), found {len(values)}", line=1)
    _check_size(path, width, height)
    return _camera(path, width, height, *values[:4], values[4:], LensModel.RADTAN, path.stem)


def _check_size(path: Path, width: int | None, height: int | None) -> None:
    if width is None or height is None:
        raise CalibrationError(
            path, "this calibration does not say the image size; give it (evp camera FILE --width W --height H) or use it with a dataset's images"
        )


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
        if PROJECTION_LINE.match(lines[0]):
            _check_size(path, width, height)
            return kitti_camera(read_kitti_projection(path, 0), width, height)
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


def distortion_model_name(camera: CameraModel) -> str:
    """The ROS / OpenCV ``distortion_model`` name of the camera's lens: ``plumb_bob``,
    ``rational_polynomial`` (8 coefficients) or ``equidistant``."""
    if camera.lens is LensModel.EQUIDISTANT:
        return "equidistant"
    return "rational_polynomial" if len(camera.distortion) == 8 else "plumb_bob"


def opencv_yaml_text(camera: CameraModel, extra: dict[str, float | int] | None = None, text: dict[str, str] | None = None) -> str:
    """OpenCV FileStorage YAML, readable by OpenCV, ORB-SLAM-style tools and :func:`read_camera`
    (which reads the lens model back from ``distortion_model``)."""
    storage = cv2.FileStorage("camera.yaml", cv2.FILE_STORAGE_WRITE | cv2.FILE_STORAGE_MEMORY)
    storage.write("camera_name", camera.name or "camera")
    storage.write("image_width", camera.width)
    storage.write("image_height", camera.height)
    storage.write("camera_matrix", camera.K)
    storage.write("distortion_model", distortion_model_name(camera))
    storage.write("distortion_coefficients", camera.distortion.reshape(1, -1))
    for key, value in (extra or {}).items():
        storage.write(key, value if isinstance(value, int) else float(value))
    for key, value in (text or {}).items():
        storage.write(key, str(value))
    return storage.releaseAndGetString()


def write_opencv_yaml(path: str | Path, camera: CameraModel, extra: dict[str, float | int] | None = None, text: dict[str, str] | None = None) -> None:
    """:func:`opencv_yaml_text` written to ``path``."""
    Path(path).write_text(opencv_yaml_text(camera, extra, text))


def ros_yaml_text(camera: CameraModel) -> str:
    """ROS ``camera_info`` YAML (as camera_calibration_parsers writes it): rectification identity,
    projection ``[K | 0]``."""

    def matrix(rows: int, cols: int, values) -> dict:
        return {"rows": rows, "cols": cols, "data": [float(v) for v in np.ravel(values)]}

    data = {
        "image_width": camera.width,
        "image_height": camera.height,
        "camera_name": camera.name or "camera",
        "camera_matrix": matrix(3, 3, camera.K),
        "distortion_model": distortion_model_name(camera),
        "distortion_coefficients": matrix(1, len(camera.distortion), camera.distortion),
        "rectification_matrix": matrix(3, 3, np.eye(3)),
        "projection_matrix": matrix(3, 4, np.hstack([camera.K, np.zeros((3, 1))])),
    }
    return yaml.safe_dump(data, sort_keys=False, default_flow_style=None)


def numbers_text(camera: CameraModel) -> str:
    """The one-line ``calib.txt`` (``fx fy cx cy k1 k2 p1 p2 k3``), which holds only a pinhole with
    up to five radial-tangential coefficients and no image size."""
    if camera.lens is not LensModel.RADTAN or len(camera.distortion) > 5:
        raise CalibrationError(
            camera.name or "camera", f"calib.txt holds fx fy cx cy k1 k2 p1 p2 k3 only; this lens ({distortion_model_name(camera)}) needs --to yaml or --to ros"
        )
    values = [camera.fx, camera.fy, camera.cx, camera.cy, *camera.distortion]
    return " ".join(repr(float(v)) for v in values) + "\n"


# what evp camera --to writes: the formats read_camera reads back
CAMERA_FILE_WRITERS = {"yaml": opencv_yaml_text, "ros": ros_yaml_text, "txt": numbers_text}
