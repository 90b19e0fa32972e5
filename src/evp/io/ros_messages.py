"""Conversions between EVP records and ROS sensor messages (ROS 1 and ROS 2 type stores).

Used by the bag/MCAP reader and by everything that records ROS-compatible files.
"""

from __future__ import annotations

import math
from pathlib import Path

import cv2
import numpy as np
from rosbags.typesys import Stores, get_typestore

from evp.calib.camera_files import camera_from_ros, distortion_model_name
from evp.types import BaroSample, CameraModel, GpsFix, ImuSample

ROS2 = get_typestore(Stores.ROS2_HUMBLE)
ROS1 = get_typestore(Stores.ROS1_NOETIC)
IMAGE = "sensor_msgs/msg/Image"
COMPRESSED_IMAGE = "sensor_msgs/msg/CompressedImage"
IMU = "sensor_msgs/msg/Imu"
NAVSAT = "sensor_msgs/msg/NavSatFix"
PRESSURE = "sensor_msgs/msg/FluidPressure"
CAMERA_INFO = "sensor_msgs/msg/CameraInfo"


def stamp_seconds(header) -> float:
    return header.stamp.sec + header.stamp.nanosec * 1e-9


def _header(store, timestamp: float, frame_id: str):
    sec = int(math.floor(timestamp))
    nanosec = min(int(round((timestamp - sec) * 1e9)), 999_999_999)
    stamp = store.types["builtin_interfaces/msg/Time"](sec=sec, nanosec=nanosec)
    fields = {"stamp": stamp, "frame_id": frame_id}
    if store is ROS1:
        fields["seq"] = 0
    return store.types["std_msgs/msg/Header"](**fields)


def _vector(store, values) -> object:
    x, y, z = (float(v) for v in values)
    return store.types["geometry_msgs/msg/Vector3"](x=x, y=y, z=z)


def image_to_msg(store, timestamp: float, image: np.ndarray, frame_id: str = "camera"):
    """sensor_msgs/Image (mono8 or bgr8)."""
    encoding = "mono8" if image.ndim == 2 else "bgr8"
    channels = 1 if image.ndim == 2 else image.shape[2]
    return store.types[IMAGE](
        header=_header(store, timestamp, frame_id),
        height=image.shape[0],
        width=image.shape[1],
        encoding=encoding,
        is_bigendian=0,
        step=image.shape[1] * channels,
        data=np.ascontiguousarray(image).reshape(-1),
    )


def jpeg_to_msg(store, timestamp: float, jpeg: bytes, frame_id: str = "camera"):
    """sensor_msgs/CompressedImage holding an already encoded JPEG."""
    return store.types[COMPRESSED_IMAGE](header=_header(store, timestamp, frame_id), format="jpeg", data=np.frombuffer(jpeg, dtype=np.uint8))


def imu_to_msg(store, sample: ImuSample, frame_id: str = "imu"):
    zeros = np.zeros(9)
    orientation = store.types["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0)
    return store.types[IMU](
        header=_header(store, sample.timestamp, frame_id),
        orientation=orientation,
        orientation_covariance=np.r_[-1.0, np.zeros(8)],
        angular_velocity=_vector(store, sample.angular_velocity_rad_s),
        angular_velocity_covariance=zeros,
        linear_acceleration=_vector(store, sample.linear_acceleration_m_s2),
        linear_acceleration_covariance=zeros,
    )


def gps_to_msg(store, fix: GpsFix, frame_id: str = "gps"):
    status = store.types["sensor_msgs/msg/NavSatStatus"](status=0, service=1)
    h = fix.horizontal_accuracy_m if math.isfinite(fix.horizontal_accuracy_m) else 0.0
    v = fix.vertical_accuracy_m if math.isfinite(fix.vertical_accuracy_m) else 0.0
    known = math.isfinite(fix.horizontal_accuracy_m)
    return store.types[NAVSAT](
        header=_header(store, fix.timestamp, frame_id),
        status=status,
        latitude=fix.latitude_deg,
        longitude=fix.longitude_deg,
        altitude=fix.altitude_m,
        position_covariance=np.diag([h * h / 2, h * h / 2, v * v]).reshape(-1),  # the horizontal accuracy is both axes' RMS
        position_covariance_type=2 if known else 0,
    )


def baro_to_msg(store, sample: BaroSample, frame_id: str = "baro"):
    return store.types[PRESSURE](header=_header(store, sample.timestamp, frame_id), fluid_pressure=sample.pressure_pa, variance=0.0)


def camera_info_to_msg(store, timestamp: float, camera: CameraModel, frame_id: str = "camera"):
    P = np.zeros((3, 4))
    P[:, :3] = camera.K
    roi = store.types["sensor_msgs/msg/RegionOfInterest"](x_offset=0, y_offset=0, height=0, width=0, do_rectify=False)
    fields = dict(
        header=_header(store, timestamp, frame_id),
        height=camera.height,
        width=camera.width,
        distortion_model=distortion_model_name(camera),
        binning_x=0,
        binning_y=0,
        roi=roi,
    )
    arrays = dict(d=camera.distortion, k=camera.K.reshape(-1), r=np.eye(3).reshape(-1), p=P.reshape(-1))
    if store is ROS1:
        arrays = {key.upper(): value for key, value in arrays.items()}
    return store.types[CAMERA_INFO](**fields, **arrays)


# --- messages to EVP records ---------------------------------------------------------------


def msg_to_image(msg, msgtype: str) -> np.ndarray | None:
    """Decoded image (grey or BGR uint8), or None when the payload cannot be decoded."""
    if msgtype == COMPRESSED_IMAGE:
        return cv2.imdecode(np.asarray(msg.data, dtype=np.uint8), cv2.IMREAD_UNCHANGED)
    data = np.asarray(msg.data, dtype=np.uint8)
    height, width, encoding = int(msg.height), int(msg.width), str(msg.encoding).lower()
    channels = {"mono8": 1, "8uc1": 1, "bgr8": 3, "rgb8": 3, "bgra8": 4, "rgba8": 4, "mono16": 2, "16uc1": 2}.get(encoding)
    if channels is None or data.size < height * int(msg.step) or int(msg.step) < width * channels:
        return None
    rows = data[: height * int(msg.step)].reshape(height, int(msg.step))[:, : width * channels]
    if channels == 2:
        dtype = ">u2" if msg.is_bigendian else "<u2"
        return cv2.convertScaleAbs(rows.copy().view(dtype).reshape(height, width), alpha=1 / 256)
    image = rows.reshape(height, width, channels) if channels > 1 else rows.reshape(height, width)
    if encoding == "rgb8":
        return cv2.cvtColor(image, cv2.COLOR_RGB2BGR)
    if encoding == "rgba8":
        return cv2.cvtColor(image, cv2.COLOR_RGBA2BGR)
    if encoding == "bgra8":
        return cv2.cvtColor(image, cv2.COLOR_BGRA2BGR)
    return image.copy()


def msg_to_imu(msg) -> ImuSample:
    w, a = msg.angular_velocity, msg.linear_acceleration
    return ImuSample(stamp_seconds(msg.header), (w.x, w.y, w.z), (a.x, a.y, a.z))


def msg_to_gps(msg) -> GpsFix | None:
    """A fix, or None when the receiver reports no fix (status -1)."""
    if msg.status.status < 0:
        return None
    cov = np.asarray(msg.position_covariance, dtype=float)
    known = msg.position_covariance_type > 0
    h = math.sqrt(cov[0] + cov[4]) if known else float("nan")  # both axes' RMS (GpsFix)
    v = math.sqrt(cov[8]) if known else float("nan")
    return GpsFix(stamp_seconds(msg.header), msg.latitude, msg.longitude, msg.altitude, h, v)


def msg_to_baro(msg) -> BaroSample:
    return BaroSample(stamp_seconds(msg.header), float(msg.fluid_pressure))


def msg_to_camera(msg, source: str | Path) -> CameraModel:
    """The camera of a ``CameraInfo`` message from ``source`` (the bag or recording, named in errors);
    its ``distortion_model`` picks the lens (plumb_bob, rational_polynomial, equidistant)."""
    K = np.asarray(getattr(msg, "k", getattr(msg, "K", None)), dtype=float)
    D = np.asarray(getattr(msg, "d", getattr(msg, "D", [])), dtype=float)
    model = str(msg.distortion_model) or None
    return camera_from_ros(Path(source), msg.width, msg.height, K, model, D, msg.header.frame_id or "camera")
