"""The EVP link protocol (version 1): JSON text messages and binary image frames over a WebSocket.

docs/protocol.md is the reference for both ends. Decoding never raises anything but
:class:`ProtocolError`, whose ``code`` is what the peer gets back in an ``error`` message.
Quaternions on the wire are (qw, qx, qy, qz), as in the EVP paper.
"""

from __future__ import annotations

import json
import math
import re
import struct
from dataclasses import asdict, dataclass
from typing import Annotated, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_serializer, field_validator

from evp.config import OrbSettings
from evp.errors import LinkError
from evp.io.image_headers import image_format, read_image_header
from evp.types import CameraModel

PROTOCOL_VERSION = 1
MAX_TEXT_BYTES = 64 * 1024
MAX_IMAGE_BYTES = 16 * 1024 * 1024
MAX_IMAGE_SIDE = 8192
# Timestamps are seconds on the sensor's clock, from 0 to 2^31 s (68 years): what a recording's
# ROS header (int32 seconds) holds, and far beyond any clock in seconds since boot or since 1970.
# A phone that sends milliseconds (1.7e12) gets a bad_timestamp error saying so, not a recording
# that cannot hold its frame.
MAX_TIMESTAMP_S = float(2**31)
# A session id as the station makes them (evp.station.store.create_session); anything else in a
# resume or a URL is refused before it reaches a query, a file name or a header.
SESSION_ID = re.compile(r"\d{8}-\d{6}-[0-9a-f]{6}")
# A camera the estimators can work with: the focal length within 1/20 and 50 times the image's
# larger side (a 170-degree fisheye to a 1-degree telephoto), the principal point on the image,
# and lens coefficients of at most 1000 in magnitude (OpenCV's rational models reach tens).
# Beyond these a camera is a typo or an attack (fx = 1e300 overflowed the estimator).
FOCAL_RANGE_PER_SIDE = (0.05, 50.0)
MAX_LENS_COEFFICIENT = 1000.0

ERROR_CODES = (
    "malformed",  # not JSON, not an object, a field missing or of the wrong type
    "oversized",  # larger than MAX_TEXT_BYTES / MAX_IMAGE_BYTES
    "unknown_type",  # a "type" (or telemetry "kind") this version does not know
    "bad_version",  # hello with another protocol version
    "bad_token",  # hello without a credential the station paired (or a revoked one)
    "busy",  # the station is at its session cap, or the session's recording at its quota
    "not_ready",  # a message that needs hello (or config) first
    "unknown_session",  # hello resuming a session the station does not have
    "out_of_order",  # sequence number or timestamp not increasing
    "corrupt_image",  # the image payload does not decode, or is not the encoding its header names
    "bad_timestamp",  # a timestamp outside [0, MAX_TIMESTAMP_S) seconds (NaN, infinite, negative, milliseconds)
    "bad_camera",  # a camera whose numbers no estimator can use (focal length, principal point, lens)
    "session_ended",  # hello resuming a session that ended (bye): ended sessions are final
    "storage_full",  # the station cannot record (disk below its free-space watermark, or writes failing): not recorded, not estimated
    "estimator_failed",  # the estimator process died on this frame (or is down): the station restarts it
    "internal",  # the station failed; the session goes on
)


class ProtocolError(LinkError):
    """A message the station refuses; ``code`` is one of ERROR_CODES."""

    def __init__(self, code: str, message: str, seq: int | None = None):
        if code not in ERROR_CODES:  # a bug in the station, not in the peer's message
            raise ValueError(f"unknown protocol error code {code!r}; known: {', '.join(ERROR_CODES)}")
        super().__init__(f"{code}: {message}")
        self.code = code
        self.message = message
        self.seq = seq


Finite = Annotated[float, Field(allow_inf_nan=False)]
Timestamp = Annotated[float, Field(allow_inf_nan=False, ge=0.0, lt=MAX_TIMESTAMP_S)]
Vector3 = Annotated[list[Finite], Field(min_length=3, max_length=3)]


class _Message(BaseModel):
    model_config = ConfigDict(extra="ignore", frozen=True)


class Hello(_Message):
    type: Literal["hello"] = "hello"
    protocol: int
    token: str = Field("", max_length=256)
    device: str = Field("", max_length=128)
    resume: str | None = Field(None, max_length=64, description="session id to continue after a dropped link")


class Welcome(_Message):
    type: Literal["welcome"] = "welcome"
    protocol: int = PROTOCOL_VERSION
    session_id: str
    resumed: bool = False
    next_seq: int = Field(0, description="first image sequence number the station accepts (continues a resumed session)")
    server: str = ""


class Config(_Message):
    """Camera and estimation settings; from the phone (what it streams) or the station (what to stream)."""

    type: Literal["config"] = "config"
    camera: CameraModel | None = Field(None, description="at the streamed resolution; its name is not sent")
    fps: Finite | None = Field(None, gt=0, le=1000)
    color_space: Literal["gray", "bgr", "rgb"] | None = None
    encoding: Literal["jpeg", "png", "raw"] | None = None
    jpeg_quality: int | None = Field(None, ge=1, le=100)
    orb: OrbSettings | None = None
    T_body_cam: Annotated[list[Finite], Field(min_length=16, max_length=16)] | None = Field(
        None, description="the camera in the IMU's frame, 4x4 row-major (metres): with it the station fuses the IMU (and GPS, barometer, range)"
    )
    answers: Literal["at_once", "after_vision"] | None = Field(
        None,
        description="at_once (default): every frame answered as it arrives with the current estimate; after_vision: after the estimator, newest frame only (as evp run)",
    )

    @field_validator("camera")
    @classmethod
    def _camera_fits_an_image_frame(cls, camera: CameraModel | None) -> CameraModel | None:
        if camera is not None:
            problem = camera_problem(camera)
            if problem:
                raise ValueError(problem)
        return camera

    @field_serializer("camera")
    def _camera_on_the_wire(self, camera: CameraModel | None) -> dict | None:
        return None if camera is None else {name: value for name, value in asdict(camera).items() if name != "name"}


def camera_problem(camera: CameraModel) -> str | None:
    """Why no estimator can use this camera (see FOCAL_RANGE_PER_SIDE), or None."""
    side = max(camera.width, camera.height)
    if side > MAX_IMAGE_SIDE:
        return f"camera of {camera.width}x{camera.height} pixels; image frames are at most {MAX_IMAGE_SIDE} on a side"
    low, high = (side * f for f in FOCAL_RANGE_PER_SIDE)
    for name, value in (("fx", camera.fx), ("fy", camera.fy)):
        if not low <= value <= high:
            return f"{name}={value:g} px for a {camera.width}x{camera.height} image; a real lens has {low:g} to {high:g}"
    if not (0 <= camera.cx <= camera.width and 0 <= camera.cy <= camera.height):
        return f"principal point ({camera.cx:g}, {camera.cy:g}) is outside the {camera.width}x{camera.height} image"
    for name, value in camera.coefficients.items():
        if abs(value) > MAX_LENS_COEFFICIENT:
            return f"lens coefficient {name}={value:g}; |{name}| <= {MAX_LENS_COEFFICIENT:g} for any real lens"
    return None


class Enable(_Message):
    type: Literal["enable"] = "enable"
    enabled: bool


class Status(_Message):
    type: Literal["status"] = "status"
    state: Literal["waiting_config", "starting", "running", "stopped", "failed"]
    estimating: bool = False
    frames_received: int = 0
    frames_estimated: int = 0
    frames_dropped: int = 0
    fps: float = 0.0
    latency_ms_p50: float = 0.0
    message: str = Field("", description="a note: the estimator starting, or why the station cannot record now (storage_full)")


class ImuTelemetry(_Message):
    type: Literal["telemetry"] = "telemetry"
    kind: Literal["imu"] = "imu"
    timestamp: Timestamp
    gyro_rad_s: Vector3
    accel_m_s2: Vector3


# IMU samples per imu_batch message: 256 rows of 7 numbers stay well inside MAX_TEXT_BYTES, and
# a second of a 200 Hz IMU fits (a batch is one frame period, 5-7 samples, when frames flow).
MAX_IMU_BATCH = 256
ImuRow = Annotated[list[Finite], Field(min_length=7, max_length=7)]


class ImuBatchTelemetry(_Message):
    """IMU samples sent together, oldest first, each row ``[t, gx, gy, gz, ax, ay, az]`` (s, rad/s,
    m/s^2); ``timestamp`` is the last row's. A companion computer's 200-400 Hz IMU sent one sample
    a message costs the station's event loop more than the frames do (the telemetry path was 75 % of
    it in a profile of two streamed flights); one message a frame period costs a seventh of that.
    The recording keeps every sample on /imu and this message verbatim."""

    type: Literal["telemetry"] = "telemetry"
    kind: Literal["imu_batch"] = "imu_batch"
    timestamp: Timestamp
    samples: list[ImuRow] = Field(min_length=1, max_length=MAX_IMU_BATCH)

    @field_validator("samples")
    @classmethod
    def _times_in_order(cls, samples: list[list[float]], info) -> list[list[float]]:
        times = [row[0] for row in samples]
        for k, t in enumerate(times):
            if not 0.0 <= t < MAX_TIMESTAMP_S:
                raise ValueError(f"row {k}: time {t!r} s is outside [0, 2^31) (seconds are expected: milliseconds?)")
        if any(later < earlier for earlier, later in zip(times, times[1:], strict=False)):
            raise ValueError("rows are not in time order (oldest first)")
        timestamp = info.data.get("timestamp")
        if timestamp is not None and times[-1] != timestamp:
            raise ValueError(f"the last row's time ({times[-1]!r}) is not the message's timestamp ({timestamp!r})")
        return samples


class GpsTelemetry(_Message):
    """A fix; latitude, longitude and altitude ``null`` (or absent) is a receiver without lock."""

    type: Literal["telemetry"] = "telemetry"
    kind: Literal["gps"] = "gps"
    timestamp: Timestamp
    latitude_deg: Finite | None = Field(None, ge=-90, le=90)
    longitude_deg: Finite | None = Field(None, ge=-180, le=180)
    altitude_m: Finite | None = None
    horizontal_accuracy_m: Finite | None = Field(None, ge=0)
    vertical_accuracy_m: Finite | None = Field(None, ge=0)


class BaroTelemetry(_Message):
    type: Literal["telemetry"] = "telemetry"
    kind: Literal["baro"] = "baro"
    timestamp: Timestamp
    pressure_pa: Finite = Field(gt=0)
    altitude_m: Finite | None = None


class RangeTelemetry(_Message):
    """A downward range finder's distance to the ground (companion computers)."""

    type: Literal["telemetry"] = "telemetry"
    kind: Literal["range"] = "range"
    timestamp: Timestamp
    distance_m: Finite = Field(gt=0)


class WheelTelemetry(_Message):
    type: Literal["telemetry"] = "telemetry"
    kind: Literal["wheel"] = "wheel"
    timestamp: Timestamp
    wheel_speeds_m_s: list[Finite] = Field(default_factory=list, max_length=16)
    forward_speed_m_s: Finite | None = None
    yaw_rate_rad_s: Finite | None = None


class EncoderTelemetry(_Message):
    """A wheel robot's raw encoder counters (left first; they wrap at ``robot.counter_bits``) and
    its gyro's yaw rate when it has one: the station makes them wheel odometry
    (:mod:`evp.fusion.wheel_encoders`), wraps and jumps included."""

    type: Literal["telemetry"] = "telemetry"
    kind: Literal["encoder"] = "encoder"
    timestamp: Timestamp
    counts: list[Annotated[int, Field(ge=0, lt=2**64)]] = Field(min_length=1, max_length=16)
    yaw_rate_rad_s: Finite | None = None


class WifiTelemetry(_Message):
    type: Literal["telemetry"] = "telemetry"
    kind: Literal["wifi"] = "wifi"
    timestamp: Timestamp
    rssi_dbm: dict[Annotated[str, Field(max_length=64)], Finite] = Field(default_factory=dict, max_length=512)


TELEMETRY = {
    "imu": ImuTelemetry,
    "imu_batch": ImuBatchTelemetry,
    "gps": GpsTelemetry,
    "baro": BaroTelemetry,
    "range": RangeTelemetry,
    "wheel": WheelTelemetry,
    "encoder": EncoderTelemetry,
    "wifi": WifiTelemetry,
}
Telemetry = ImuTelemetry | ImuBatchTelemetry | GpsTelemetry | BaroTelemetry | RangeTelemetry | WheelTelemetry | EncoderTelemetry | WifiTelemetry


def telemetry_records(message: Telemetry) -> list:
    """The pipeline's records for a telemetry message (several for an IMU batch; absent optional
    numbers become NaN, as the dataset readers give them); a GPS fix without lock has a NaN
    position."""
    from evp.types import ImuSample

    if isinstance(message, ImuBatchTelemetry):
        return [ImuSample(row[0], tuple(row[1:4]), tuple(row[4:7])) for row in message.samples]
    return [telemetry_record(message)]


def telemetry_record(message: Telemetry):
    """The pipeline's record for a single-sample telemetry message (see ``telemetry_records``)."""
    from evp.types import BaroSample, EncoderCounts, GpsFix, ImuSample, RangeSample, WheelOdometry, WifiScan

    def value(number: float | None) -> float:
        return math.nan if number is None else number

    if isinstance(message, ImuTelemetry):
        return ImuSample(message.timestamp, tuple(message.gyro_rad_s), tuple(message.accel_m_s2))
    if isinstance(message, GpsTelemetry):
        m = message
        return GpsFix(
            m.timestamp, value(m.latitude_deg), value(m.longitude_deg), value(m.altitude_m), value(m.horizontal_accuracy_m), value(m.vertical_accuracy_m)
        )
    if isinstance(message, BaroTelemetry):
        return BaroSample(message.timestamp, message.pressure_pa, value(message.altitude_m))
    if isinstance(message, RangeTelemetry):
        return RangeSample(message.timestamp, message.distance_m)
    if isinstance(message, WheelTelemetry):
        return WheelOdometry(message.timestamp, tuple(message.wheel_speeds_m_s), value(message.forward_speed_m_s), value(message.yaw_rate_rad_s))
    if isinstance(message, EncoderTelemetry):
        return EncoderCounts(message.timestamp, tuple(message.counts), value(message.yaw_rate_rad_s))
    return WifiScan(message.timestamp, dict(message.rssi_dbm))


class Pose(_Message):
    """The estimate for one image: camera-to-world translation and rotation (qw, qx, qy, qz)."""

    type: Literal["pose"] = "pose"
    seq: int
    timestamp: float
    t: list[float]
    q: list[float]
    state: Literal["NOT_INITIALIZED", "OK", "LOST", "RELOCALIZED"]
    quality: int = Field(0, ge=0, le=100)
    reset_counter: int = 0
    covariance: list[float] | None = Field(None, description="6x6 row-major over (x, y, z, roll, pitch, yaw), when known")
    processing_ms: float = 0.0
    metric: bool = Field(False, description="metres, gravity-aligned (z up): the navigation filter's pose; else the estimator's map units")
    scale_known: bool = False
    georeferenced: bool = Field(False, description="the world is ENU at the take-off point (the first GPS fix with a lock)")
    gps_trusted: bool = False
    gps: Literal["none", "off", "aligning", "trusted", "untrusted", "unavailable"] = Field("none", description="GPS as the filter uses it ('none': no filter)")
    velocity: list[float] | None = Field(None, description="m/s in the world frame, when metric")
    velocity_covariance: list[float] | None = Field(None, description="3x3 row-major, (m/s)^2, world frame, when metric")
    latitude_deg: float | None = None
    longitude_deg: float | None = None
    altitude_m: float | None = Field(None, description="WGS-84 ellipsoid height, when georeferenced")
    visual_age_s: float | None = Field(None, description="the frame's time minus the last frame vision tracked (None: none yet)")


class Dropped(_Message):
    """A frame that gets no pose: stale (a newer one arrived first), estimation off, or no camera yet."""

    type: Literal["dropped"] = "dropped"
    seq: int
    reason: Literal["stale", "estimation_off", "not_configured", "closing", "overload"]


class Log(_Message):
    type: Literal["log"] = "log"
    level: Literal["debug", "info", "warning", "error"] = "info"
    text: str = Field(max_length=4096)


class Error(_Message):
    type: Literal["error"] = "error"
    code: str
    message: str
    seq: int | None = None


class Bye(_Message):
    type: Literal["bye"] = "bye"


class Velocity(_Message):
    """The station drives a wheel robot: forward speed and turn rate (counter-clockwise). The
    station repeats the current command every ``robot.command_interval_s``; the robot stops by
    itself when none came for ``robot.watchdog_timeout_s`` (:mod:`evp.mobile.robot`)."""

    type: Literal["velocity"] = "velocity"
    linear_m_s: Finite
    angular_rad_s: Finite


class Heartbeat(_Message):
    """Sent by both ends on an idle link (``station.heartbeat_interval_s``): a link that stays
    silent for ``heartbeat_timeout_s`` is dead even without a close frame. Link-level: it is
    neither recorded nor answered."""

    type: Literal["heartbeat"] = "heartbeat"


HEARTBEAT_TEXT = '{"type": "heartbeat"}'


def is_heartbeat(text: str) -> bool:
    """A heartbeat, told apart without a full decode (it arrives every second on every link)."""
    if len(text) > 64 or "heartbeat" not in text:
        return False
    try:
        data = json.loads(text)
    except ValueError:
        return False
    return isinstance(data, dict) and data.get("type") == "heartbeat"


MESSAGES: dict[str, type[_Message]] = {
    "hello": Hello,
    "welcome": Welcome,
    "config": Config,
    "enable": Enable,
    "status": Status,
    "pose": Pose,
    "dropped": Dropped,
    "log": Log,
    "error": Error,
    "bye": Bye,
    "heartbeat": Heartbeat,
    "velocity": Velocity,
}
Message = Hello | Welcome | Config | Enable | Status | Pose | Dropped | Log | Error | Bye | Heartbeat | Velocity | Telemetry


def _reject_constant(name: str) -> float:
    raise ValueError(f"{name} is not JSON")


def decode_text(text: str | bytes) -> Message:
    """One JSON text message; any problem raises ProtocolError."""
    if len(text) > MAX_TEXT_BYTES:
        raise ProtocolError("oversized", f"text message of {len(text)} bytes (limit {MAX_TEXT_BYTES})")
    try:
        data = json.loads(text, parse_constant=_reject_constant)
    except (ValueError, RecursionError) as exc:
        raise ProtocolError("malformed", f"not JSON ({str(exc)[:80]})") from None
    if not isinstance(data, dict):
        raise ProtocolError("malformed", f"a message is a JSON object, got {type(data).__name__}")
    kind = data.get("type")
    if kind == "telemetry":
        sensor = data.get("kind")
        model = TELEMETRY.get(sensor) if isinstance(sensor, str) else None
        if model is None:
            raise ProtocolError("unknown_type", f"unknown telemetry kind {str(sensor)[:40]!r} (known: {', '.join(TELEMETRY)})")
    else:
        model = MESSAGES.get(kind) if isinstance(kind, str) else None
        if model is None:
            raise ProtocolError("unknown_type", f"unknown message type {str(kind)[:40]!r}")
    try:
        return model.model_validate(data)
    except ValidationError as exc:
        first = exc.errors()[0]
        where = ".".join(str(p) for p in first["loc"]) or kind
        code = {"timestamp": "bad_timestamp", "camera": "bad_camera"}.get(str(first["loc"][0]) if first["loc"] else "", "malformed")
        hint = " (seconds are expected: milliseconds?)" if code == "bad_timestamp" and first["type"] == "less_than" else ""
        raise ProtocolError(code, f"{kind}: {where}: {first['msg']}{hint}") from None
    except RecursionError:
        raise ProtocolError("malformed", f"{kind}: nested too deeply") from None


def encode(message: _Message) -> str:
    return message.model_dump_json(exclude_none=True)


# --- images ---------------------------------------------------------------------------------

IMAGE_MAGIC = b"EVPI"
IMAGE_HEADER = struct.Struct("<4sBBHIHHdI4x")  # magic, version, encoding, reserved, seq, width, height, timestamp, length
ENCODINGS = {1: "jpeg", 2: "png", 3: "gray8", 4: "bgr8", 5: "rgb8"}
ENCODING_IDS = {name: code for code, name in ENCODINGS.items()}
RAW_CHANNELS = {"gray8": 1, "bgr8": 3, "rgb8": 3}


@dataclass(frozen=True)
class ImageMessage:
    """One camera image as sent: the payload is decoded only when the estimator needs it."""

    seq: int
    timestamp: float
    encoding: str
    width: int
    height: int
    payload: bytes

    def pack(self) -> bytes:
        header = IMAGE_HEADER.pack(
            IMAGE_MAGIC, PROTOCOL_VERSION, ENCODING_IDS[self.encoding], 0, self.seq, self.width, self.height, self.timestamp, len(self.payload)
        )
        return header + self.payload


def decode_image(data: bytes) -> ImageMessage:
    """The header of one binary image frame, checked against its payload."""
    if len(data) > MAX_IMAGE_BYTES + IMAGE_HEADER.size:
        raise ProtocolError("oversized", f"image frame of {len(data)} bytes (limit {MAX_IMAGE_BYTES})")
    if len(data) < IMAGE_HEADER.size:
        raise ProtocolError("malformed", f"image frame of {len(data)} bytes is shorter than its {IMAGE_HEADER.size}-byte header")
    magic, version, encoding_id, _, seq, width, height, timestamp, length = IMAGE_HEADER.unpack_from(data)
    if magic != IMAGE_MAGIC:
        raise ProtocolError("malformed", f"image frame starts with {magic!r}, not {IMAGE_MAGIC!r}")
    if version != PROTOCOL_VERSION:
        raise ProtocolError("bad_version", f"image frame of protocol version {version}, station speaks {PROTOCOL_VERSION}", seq)
    encoding = ENCODINGS.get(encoding_id)
    if encoding is None:
        raise ProtocolError("unknown_type", f"image encoding {encoding_id} (known: {ENCODINGS})", seq)
    if not (0 < width <= MAX_IMAGE_SIDE and 0 < height <= MAX_IMAGE_SIDE):
        raise ProtocolError("malformed", f"image size {width}x{height}", seq)
    if not 0.0 <= timestamp < MAX_TIMESTAMP_S:  # also NaN and infinities
        hint = " (seconds are expected: milliseconds?)" if timestamp >= MAX_TIMESTAMP_S else ""
        raise ProtocolError("bad_timestamp", f"image timestamp {timestamp!r} is outside [0, {MAX_TIMESTAMP_S:.0f}) s{hint}", seq)
    payload = data[IMAGE_HEADER.size :]
    if len(payload) != length:
        raise ProtocolError("malformed", f"image payload is {len(payload)} bytes, header says {length}", seq)
    if encoding in RAW_CHANNELS and length != width * height * RAW_CHANNELS[encoding]:
        raise ProtocolError("malformed", f"{encoding} {width}x{height} needs {width * height * RAW_CHANNELS[encoding]} bytes, got {length}", seq)
    return ImageMessage(seq, timestamp, encoding, width, height, payload)


def check_image_header(message: ImageMessage) -> None:
    """A JPEG or PNG payload is that format, of the announced size, 8 bits per sample: read from
    its header (no decoding), so a lying payload is refused before it is recorded or decoded."""
    if message.encoding in RAW_CHANNELS:
        return  # its length was checked against the size
    header = read_image_header(message.payload)
    found = image_format(message.payload)
    if found != message.encoding:
        raise ProtocolError("corrupt_image", f"payload is {found or 'neither JPEG nor PNG'}, the frame says {message.encoding}", message.seq)
    if header is None:
        raise ProtocolError("corrupt_image", f"{message.encoding} header is cut off or malformed", message.seq)
    if (header.width, header.height) != (message.width, message.height):
        raise ProtocolError(
            "corrupt_image", f"{message.encoding} is {header.width}x{header.height}, the frame says {message.width}x{message.height}", message.seq
        )
    if header.bit_depth > 8:
        raise ProtocolError("corrupt_image", f"{header.bit_depth}-bit {message.encoding}; images are 8 bits per sample", message.seq)


def image_pixels(message: ImageMessage) -> np.ndarray:
    """The image as grey or BGR uint8; a payload that does not decode to the announced size raises."""
    import cv2

    check_image_header(message)
    if message.encoding in RAW_CHANNELS:
        channels = RAW_CHANNELS[message.encoding]
        pixels = np.frombuffer(message.payload, dtype=np.uint8).reshape(message.height, message.width, channels)
        if message.encoding == "rgb8":
            return cv2.cvtColor(pixels, cv2.COLOR_RGB2BGR)
        return pixels[:, :, 0].copy() if channels == 1 else pixels.copy()
    pixels = cv2.imdecode(np.frombuffer(message.payload, dtype=np.uint8), cv2.IMREAD_UNCHANGED) if message.payload else None
    if pixels is None:
        raise ProtocolError("corrupt_image", f"{message.encoding} payload of {len(message.payload)} bytes does not decode", message.seq)
    if pixels.shape[:2] != (message.height, message.width):
        raise ProtocolError("corrupt_image", f"decodes to {pixels.shape[1]}x{pixels.shape[0]}, header says {message.width}x{message.height}", message.seq)
    if pixels.dtype != np.uint8 or pixels.ndim not in (2, 3):
        raise ProtocolError("corrupt_image", f"decodes to {pixels.dtype} of shape {pixels.shape}, not 8-bit grey or colour", message.seq)
    if pixels.ndim == 3 and pixels.shape[2] == 4:
        pixels = cv2.cvtColor(pixels, cv2.COLOR_BGRA2BGR)
    return pixels


def encode_image(image: np.ndarray, seq: int, timestamp: float, encoding: str = "jpeg", jpeg_quality: int = 90) -> ImageMessage:
    """Pack a grey or BGR uint8 image; ``encoding`` is jpeg, png or raw (gray8/bgr8 by channels)."""
    import cv2

    height, width = image.shape[:2]
    if encoding == "raw":
        encoding = "gray8" if image.ndim == 2 else "bgr8"
        payload = np.ascontiguousarray(image).tobytes()
    else:
        params = [cv2.IMWRITE_JPEG_QUALITY, jpeg_quality] if encoding == "jpeg" else [cv2.IMWRITE_PNG_COMPRESSION, 1]
        ok, buffer = cv2.imencode(".jpg" if encoding == "jpeg" else ".png", image, params)
        if not ok:
            raise ValueError(f"OpenCV could not encode a {width}x{height} image as {encoding}")
        payload = buffer.tobytes()
    return ImageMessage(seq, float(timestamp), encoding, width, height, payload)
