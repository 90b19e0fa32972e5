"""The link protocol: round trips, the specific error for each kind of bad message, and fuzzing."""

from __future__ import annotations

import json

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from evp.station.protocol import (
    IMAGE_HEADER,
    MAX_TEXT_BYTES,
    PROTOCOL_VERSION,
    Config,
    GpsTelemetry,
    Hello,
    ImageMessage,
    ImuTelemetry,
    Pose,
    ProtocolError,
    decode_image,
    decode_text,
    encode,
    encode_image,
    image_pixels,
)
from tests.io.builders import png_header_only


def test_messages_round_trip():
    messages = [
        Hello(protocol=PROTOCOL_VERSION, token="t", device="phone"),
        Config.model_validate({"camera": {"width": 640, "height": 380, "fx": 494.1, "fy": 494.2, "cx": 319.9, "cy": 173.6, "k1": 0.04}, "fps": 30}),
        ImuTelemetry(timestamp=1.5, gyro_rad_s=[0.1, 0.2, 0.3], accel_m_s2=[0.0, 0.0, 9.81]),
        GpsTelemetry(timestamp=2.0, latitude_deg=3.37, longitude_deg=-76.53, altitude_m=995.0, horizontal_accuracy_m=3.0),
        Pose(seq=7, timestamp=0.25, t=[1.0, 2.0, 3.0], q=[1.0, 0.0, 0.0, 0.0], state="OK", quality=80),
    ]
    for message in messages:
        assert decode_text(encode(message)) == message


@pytest.mark.parametrize("encoding", ["jpeg", "png", "raw"])
@pytest.mark.parametrize("channels", [1, 3])
def test_images_round_trip(encoding, channels):
    y, x = np.mgrid[0:38, 0:64]
    grey = (100 + 60 * np.sin(x / 6.0) * np.cos(y / 5.0)).astype(np.uint8)
    image = grey if channels == 1 else np.dstack([grey, grey // 2, 255 - grey])
    message = decode_image(encode_image(image, seq=3, timestamp=12.5, encoding=encoding).pack())
    assert (message.seq, message.timestamp, message.width, message.height) == (3, 12.5, 64, 38)
    pixels = image_pixels(message)
    assert pixels.shape[:2] == image.shape[:2]
    if encoding != "jpeg":
        assert np.array_equal(pixels.reshape(image.shape), image)
    else:
        assert np.abs(pixels.astype(int).reshape(image.shape) - image).mean() < 4


@pytest.mark.parametrize(
    ("text", "code", "words"),
    [
        ("{not json", "malformed", "not JSON"),
        ("[1, 2]", "malformed", "JSON object"),
        ('{"type": "teleport"}', "unknown_type", "teleport"),
        ('{"type": "telemetry", "kind": "sonar", "timestamp": 1}', "unknown_type", "sonar"),
        ('{"type": "hello"}', "malformed", "protocol"),
        ('{"type": "telemetry", "kind": "imu", "timestamp": 1, "gyro_rad_s": [0, 0], "accel_m_s2": [0, 0, 9.8]}', "malformed", "gyro_rad_s"),
        ('{"type": "telemetry", "kind": "gps", "timestamp": 1, "latitude_deg": 91, "longitude_deg": 0, "altitude_m": 0}', "malformed", "latitude_deg"),
        ('{"type": "telemetry", "kind": "baro", "timestamp": NaN, "pressure_pa": 1e5}', "malformed", "not JSON"),
        ('{"type": "config", "camera": {"width": 640, "height": 380, "fx": -1, "fy": 1, "cx": 0, "cy": 0}}', "bad_camera", "focal lengths must be positive"),
        ('{"type": "config", "camera": {"width": 640, "height": 380, "fx": 1e300, "fy": 500, "cx": 320, "cy": 190}}', "bad_camera", "fx=1e+300"),
        ('{"type": "config", "camera": {"width": 640, "height": 380, "fx": 500, "fy": 500, "cx": 9000, "cy": 190}}', "bad_camera", "principal point"),
        ('{"type": "config", "camera": {"width": 640, "height": 380, "fx": 500, "fy": 500, "cx": 320, "cy": 190, "k1": 1e9}}', "bad_camera", "k1"),
        ('{"type": "telemetry", "kind": "imu", "timestamp": 1.7e12, "gyro_rad_s": [0, 0, 0], "accel_m_s2": [0, 0, 9.8]}', "bad_timestamp", "milliseconds"),
        ('{"type": "telemetry", "kind": "gps", "timestamp": -1}', "bad_timestamp", "greater than or equal to 0"),
        ('{"type": "telemetry", "kind": "range", "timestamp": 1e400, "distance_m": 1}', "bad_timestamp", "finite"),
        ('{"type": "enable", "enabled": "maybe"}', "malformed", "enabled"),
        ("[" * 5000 + "]" * 5000, "malformed", ""),
        (json.dumps({"type": "log", "text": "x" * (MAX_TEXT_BYTES + 1)}), "oversized", "limit"),
    ],
)
def test_bad_text_gets_a_specific_error(text, code, words):
    with pytest.raises(ProtocolError) as info:
        decode_text(text)
    assert info.value.code == code
    assert words in info.value.message


def _frame(**overrides) -> bytes:
    fields = dict(magic=b"EVPI", version=PROTOCOL_VERSION, encoding=1, seq=1, width=4, height=2, timestamp=1.0, length=None, payload=b"\xff\xd8junk")
    fields.update(overrides)
    payload = fields.pop("payload")
    length = len(payload) if fields["length"] is None else fields["length"]
    header = IMAGE_HEADER.pack(
        fields["magic"], fields["version"], fields["encoding"], 0, fields["seq"], fields["width"], fields["height"], fields["timestamp"], length
    )
    return header + payload


@pytest.mark.parametrize(
    ("data", "code"),
    [
        (b"EVPI", "malformed"),
        (_frame(magic=b"JPEG"), "malformed"),
        (_frame(version=9), "bad_version"),
        (_frame(encoding=77), "unknown_type"),
        (_frame(width=0), "malformed"),
        (_frame(timestamp=float("inf")), "bad_timestamp"),
        (_frame(timestamp=float("nan")), "bad_timestamp"),
        (_frame(timestamp=-0.5), "bad_timestamp"),
        (_frame(timestamp=2.0**31), "bad_timestamp"),  # a phone sending milliseconds: 1.7e12
        (_frame(timestamp=1.7e12), "bad_timestamp"),
        (_frame(length=1000), "malformed"),
        (_frame(encoding=3, payload=b"\x00" * 7), "malformed"),  # gray8 4x2 needs 8 bytes
    ],
)
def test_bad_image_frames_get_a_specific_error(data, code):
    with pytest.raises(ProtocolError) as info:
        decode_image(data)
    assert info.value.code == code


def test_corrupt_and_wrong_size_jpeg_are_corrupt_image():
    corrupt = decode_image(_frame())
    with pytest.raises(ProtocolError, match="header is cut off or malformed") as info:
        image_pixels(corrupt)
    assert info.value.code == "corrupt_image" and info.value.seq == 1
    real = encode_image(np.full((20, 30), 128, np.uint8), 2, 1.0, "jpeg")
    lying = ImageMessage(real.seq, real.timestamp, "jpeg", 31, 20, real.payload)
    with pytest.raises(ProtocolError, match="the frame says 31x20"):
        image_pixels(lying)
    body = real.payload[:200] + bytes(len(real.payload) - 200)  # a valid header, a body that does not decode
    with pytest.raises(ProtocolError, match="does not decode|decodes to"):
        image_pixels(ImageMessage(3, 1.0, "jpeg", 30, 20, body))


def test_payloads_that_are_not_what_they_claim_are_refused_from_their_header():
    """Finding 5: a float64 TIFF sent as "png" killed the estimator; a 20000x20000 PNG is
    refused from its header, never decoded; a 16-bit PNG is not what the estimators take."""
    import cv2

    ok, tiff = cv2.imencode(".tiff", np.random.default_rng(0).random((20, 30)).astype(np.float32))
    assert ok
    with pytest.raises(ProtocolError, match="neither JPEG nor PNG, the frame says png") as info:
        image_pixels(ImageMessage(4, 1.0, "png", 30, 20, tiff.tobytes()))
    assert info.value.code == "corrupt_image"
    huge = png_header_only(20000, 20000)
    with pytest.raises(ProtocolError, match="png is 20000x20000, the frame says 30x20"):
        image_pixels(ImageMessage(5, 1.0, "png", 30, 20, huge))
    ok, deep = cv2.imencode(".png", np.full((20, 30), 1000, np.uint16))
    with pytest.raises(ProtocolError, match="16-bit png"):
        image_pixels(ImageMessage(6, 1.0, "png", 30, 20, deep.tobytes()))


json_values = st.recursive(
    st.none() | st.booleans() | st.integers() | st.floats(allow_nan=False) | st.text(max_size=20),
    lambda children: st.lists(children, max_size=4) | st.dictionaries(st.text(max_size=12), children, max_size=5),
    max_leaves=20,
)
message_like = st.fixed_dictionaries(
    {"type": st.sampled_from(["hello", "config", "enable", "telemetry", "pose", "log", "bye", "status", "error", "x"])},
    optional={
        "kind": st.sampled_from(["imu", "gps", "baro", "wheel", "wifi", "?"]),
        "timestamp": json_values,
        "camera": json_values,
        "protocol": json_values,
        "enabled": json_values,
        "gyro_rad_s": json_values,
    },
)


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.one_of(st.text(max_size=300), st.binary(max_size=300), message_like.map(json.dumps), json_values.map(json.dumps)))
def test_fuzzed_text_raises_only_protocol_errors(text):
    try:
        decode_text(text)
    except ProtocolError as exc:
        assert exc.code in ("malformed", "unknown_type", "oversized", "bad_timestamp", "bad_camera")


@settings(max_examples=300, deadline=None)
@given(st.binary(max_size=200), st.integers(0, 255), st.integers(0, 255), st.integers(0, 2**32 - 1), st.integers(0, 300), st.integers(0, 300))
def test_fuzzed_images_raise_only_protocol_errors(payload, version, encoding, length, width, height):
    header = IMAGE_HEADER.pack(b"EVPI", version, encoding, 0, 5, width, height, 1.0, length)
    for data in (payload, header + payload, header[: len(payload) % IMAGE_HEADER.size] + payload):
        try:
            image_pixels(decode_image(data))
        except ProtocolError:
            pass


def test_protocol_errors_are_link_errors_and_codes_are_checked_without_assert():
    from evp.errors import EvpError, ExitCode, LinkError

    error = ProtocolError("malformed", "x")
    assert isinstance(error, LinkError) and isinstance(error, EvpError) and error.exit_code == ExitCode.LINK
    with pytest.raises(ValueError, match="unknown protocol error code"):
        ProtocolError("no_such_code", "x")


def test_config_carries_the_one_camera_model_and_orb_settings():
    from evp.config import OrbSettings
    from evp.types import CameraModel

    camera = CameraModel(640, 380, 494.1, 494.2, 319.9, 173.6, k1=0.04, name="phone")
    message = Config(camera=camera, orb=OrbSettings(n_features=1500))
    wire = json.loads(encode(message))
    assert "name" not in wire["camera"] and wire["camera"]["k1"] == 0.04 and wire["orb"]["n_features"] == 1500
    decoded = decode_text(encode(message))
    assert isinstance(decoded.camera, CameraModel) and decoded.camera == CameraModel(640, 380, 494.1, 494.2, 319.9, 173.6, k1=0.04)
    assert isinstance(decoded.orb, OrbSettings) and decoded.orb.n_features == 1500
    for bad, words in (({"fx": 1e999}, "finite"), ({"width": 9000}, "at most 8192")):
        fields = {"width": 640, "height": 380, "fx": 494.1, "fy": 494.2, "cx": 319.9, "cy": 173.6, **bad}
        with pytest.raises(ProtocolError, match=words) as info:
            decode_text(json.dumps({"type": "config", "camera": fields}).replace("Infinity", "1e999"))
        assert info.value.code == "bad_camera"


def test_a_fisheye_config_dumps_to_json_and_back():
    """The station's snapshot is ``json.dumps`` of ``model_dump()`` (python mode): the lens must
    leave as its name, not as an enum JSON cannot write, or every operator feed closes."""
    from evp.types import CameraModel, LensModel

    camera = CameraModel(640, 380, 210.0, 210.0, 319.5, 189.5, k1=0.003, k2=0.0007, lens=LensModel.EQUIDISTANT)
    dumped = json.loads(json.dumps(Config(camera=camera).model_dump()))
    assert dumped["camera"]["lens"] == "equidistant"
    assert decode_text(json.dumps({"type": "config", "camera": dumped["camera"]})).camera == camera
