"""A hostile mobile station for the station's fuzzers (tests/station/test_fuzz.py, bench/station_fuzz.py).

:class:`HostileClient` makes every message kind of the protocol, valid and not: each text type
(also the station's own, unknown ones, broken JSON, deep nesting, oversized), every telemetry kind
with good and bad fields, configs with sane and absurd cameras, image frames that are good, out
of order, of the wrong size, corrupt, lying about their format or size, and timestamps of any
magnitude (0, negative, 2^31 s, milliseconds, 1e308, NaN, infinities, subnormals).

:func:`fuzz_station` drives a real :class:`evp.station.base_station.Station` (its sessions,
estimator processes, database and recordings) in-process, socket-free, as the WebSocket
endpoint does, and checks the station's promises: no message raises, no estimator process dies,
every image frame gets exactly one answer (a refusal at once, or a pose, ``dropped`` or error
once estimated), and memory does not grow.
"""

from __future__ import annotations

import asyncio
import gc
import json
import math
import time
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from evp.config import Settings
from evp.station.base_station import Station
from evp.station.protocol import IMAGE_HEADER, IMAGE_MAGIC, PROTOCOL_VERSION, Hello, ImageMessage, ProtocolError, decode_image, decode_text, encode_image
from evp.station.store import SessionStore
from tests.io.builders import png_header_only

WIDTH, HEIGHT = 64, 48
CAMERA = {"width": WIDTH, "height": HEIGHT, "fx": 60.0, "fy": 60.0, "cx": 32.0, "cy": 24.0}
# every one refused: out of range, or (0, 5e-324) before any plausible time; a valid far-ahead time
# would be taken and leave every later frame of the session out of order
HOSTILE_TIMES = (0.0, -1.0, -1e-300, 2.0**31, 2.0**31 + 1e-3, 1.7e12, 1e308, -1e308, 5e-324, math.nan, math.inf, -math.inf)
TELEMETRY = {
    "imu": {"gyro_rad_s": [0.0, 0.01, -0.02], "accel_m_s2": [0.1, -0.2, 9.8]},
    "gps": {"latitude_deg": 3.37, "longitude_deg": -76.53, "altitude_m": 995.0, "horizontal_accuracy_m": 4.0},
    "baro": {"pressure_pa": 90000.0, "altitude_m": 995.0},
    "range": {"distance_m": 1.5},
    "wheel": {"wheel_speeds_m_s": [0.5, 0.5], "forward_speed_m_s": 0.5, "yaw_rate_rad_s": 0.0},
    "wifi": {"rssi_dbm": {"aa:bb": -60.0, "cc:dd": -71.0}},
}
ABSURD_CAMERA = {
    "fx": (1e300, -1.0, 0.0, 1e9, 1e-9, math.inf),
    "fy": (1e300, -1.0, 0.0, 1e9),
    "cx": (-1e6, 1e300, 99999.0),
    "cy": (-1.0, 1e300, math.nan),
    "k1": (1e300, 1e9, -1e9),
    "width": (0.0, -5.0, 99999.0),
    "height": (0.0, 1e12),
}
BAD_VALUES = (None, "x", [], {}, -1, 1e999, True, [1, 2], "NaN", 10**40)


def _frame(seq: int, timestamp: float, encoding_id: int, width: int, height: int, payload: bytes, **header) -> bytes:
    fields = {"magic": IMAGE_MAGIC, "version": PROTOCOL_VERSION, "length": len(payload), **header}
    packed = IMAGE_HEADER.pack(fields["magic"], fields["version"], encoding_id, 0, seq % 2**32, width, height, timestamp, fields["length"] % 2**32)
    return packed + payload


class HostileClient:
    """One fuzzing mobile station: ``message()`` is the next text (str) or image frame (bytes)."""

    def __init__(self, seed: int, bye_every: int = 5000, new_estimator_every: int = 2000):
        """About one message in ``bye_every`` ends the session, one in ``new_estimator_every`` is a
        config that starts a new estimator (a process start: seconds)."""
        self.rng = np.random.default_rng(seed)
        self.new_estimator_every = new_estimator_every
        self.seq = 0
        self.time = 1.0
        self.telemetry_time = 1.0
        self.bye_every = bye_every
        noise = [self.rng.integers(0, 256, (HEIGHT, WIDTH), dtype=np.uint8) for _ in range(4)]
        self.images = [cv2.GaussianBlur(image, (5, 5), 1.5) for image in noise]
        ok, tiff = cv2.imencode(".tiff", self.rng.random((HEIGHT, WIDTH)).astype(np.float32))
        ok16, deep = cv2.imencode(".png", self.rng.integers(0, 65535, (HEIGHT, WIDTH), dtype=np.uint16))
        assert ok and ok16
        self.tiff, self.deep_png = tiff.tobytes(), deep.tobytes()

    # --- timestamps -----------------------------------------------------------------------------

    def _time(self, current: float) -> float:
        """Mostly the next plausible time, else any magnitude."""
        if self.rng.random() < 0.8:
            return current + float(self.rng.uniform(0.001, 0.05))
        if self.rng.random() < 0.5:
            return float(self.rng.choice(HOSTILE_TIMES))
        if self.rng.random() < 0.5:
            return -float(10.0 ** self.rng.uniform(-12, 22))
        return float(10.0 ** self.rng.uniform(math.log10(2.0**31), 22))  # at least 2^31 s

    # --- text -----------------------------------------------------------------------------------

    def text(self) -> str:
        r = self.rng.random()
        if r < 0.45:
            return self._telemetry()
        if r < 0.55:
            return self._config()
        if r < 0.85:
            return json.dumps(self._other())
        return self._broken()

    def _telemetry(self) -> str:
        kind = str(self.rng.choice([*TELEMETRY, "sonar"]))
        t = self._time(self.telemetry_time)
        if math.isfinite(t) and 0 <= t < 2**31:
            self.telemetry_time = max(self.telemetry_time, t)
        message = {"type": "telemetry", "kind": kind, "timestamp": t, **TELEMETRY.get(kind, {})}
        if self.rng.random() < 0.2 and len(message) > 3:
            name = str(self.rng.choice([k for k in message if k not in ("type", "kind")]))
            message[name] = BAD_VALUES[self.rng.integers(len(BAD_VALUES))]
        return json.dumps(message)  # NaN and Infinity become JSON's forbidden tokens: refused as not JSON

    def _config(self) -> str:
        camera = dict(CAMERA)
        r = self.rng.random()
        if r < 0.3:  # absurd cameras (a valid other camera would start a new estimator)
            name = str(self.rng.choice(list(ABSURD_CAMERA)))
            camera[name] = float(self.rng.choice(ABSURD_CAMERA[name]))
        elif r < 0.35:
            camera = BAD_VALUES[self.rng.integers(len(BAD_VALUES))]
        message = {"type": "config", "camera": camera}
        if self.rng.random() * self.new_estimator_every < 10:  # configs are 6 % of the messages
            message["answers"] = str(self.rng.choice(["at_once", "after_vision"]))
        elif self.rng.random() < 0.05:
            message["answers"] = "sometimes"
        if self.rng.random() < 0.05:
            message["T_body_cam"] = [1.0, 2.0]  # refused: 16 numbers
        return json.dumps(message)

    def _other(self) -> dict:
        kind = str(self.rng.choice(["enable", "log", "error", "hello", "welcome", "status", "pose", "dropped", "warp"]))
        examples = {
            "enable": {"enabled": bool(self.rng.random() < 0.8)},
            "log": {"level": str(self.rng.choice(["debug", "info", "warning", "error", "panic"])), "text": "x" * int(self.rng.integers(0, 200))},
            "error": {"code": "phone", "message": "camera busy"},
            "hello": {"protocol": 1},
            "welcome": {"session_id": "x"},
            "status": {"state": "running"},
            "pose": {"seq": 1, "timestamp": 1.0, "t": [0, 0, 0], "q": [1, 0, 0, 0], "state": "OK"},
            "dropped": {"seq": 1, "reason": "stale"},
            "warp": {},
        }
        return {"type": kind, **examples[kind]}

    def _broken(self) -> str:
        choice = int(self.rng.integers(7))
        if choice == 0:
            return "{oops"
        if choice == 1:
            return "[1, 2, 3]"
        if choice == 2:
            return "[" * 3000 + "]" * 3000
        if choice == 3 and self.rng.random() < 0.05:
            return json.dumps({"type": "log", "text": "y" * 70000})  # oversized
        if choice == 4:
            return '{"type": "telemetry", "kind": "imu", "timestamp": NaN}'
        if choice == 5:
            return self.rng.bytes(int(self.rng.integers(1, 200))).decode("latin-1")
        return '{"type": null}'

    # --- image frames ---------------------------------------------------------------------------

    def frame(self) -> bytes:
        """The next image frame; later good frames go on after any valid time sent (the station
        may have taken a hostile frame with a plausible header and a far-ahead time)."""
        data = self._frame()
        if len(data) >= IMAGE_HEADER.size:
            timestamp = IMAGE_HEADER.unpack_from(data)[7]
            if 0 <= timestamp < 2**31:
                self.time = max(self.time, timestamp)
        return data

    def _frame(self) -> bytes:
        r = self.rng.random()
        image = self.images[self.seq % len(self.images)]
        if r < 0.55:  # a good next frame
            t = self._time(self.time)
            self.seq += 1
            encoding = str(self.rng.choice(["png", "jpeg", "raw"]))
            return encode_image(image, self.seq, t, encoding).pack()
        good = encode_image(image, self.seq + 1, self.time + 0.01, "png")
        choice = int(self.rng.integers(13))
        if choice == 0:  # sequence repeats
            return encode_image(image, self.seq, self.time + 0.01, "png").pack()
        if choice == 1:  # time goes back
            return encode_image(image, self.seq + 1, self.time - 0.5, "png").pack()
        if choice == 2:  # wrong size for the camera
            return encode_image(image[:20, :30], self.seq + 1, self.time + 0.01, "png").pack()
        if choice == 3:  # a corrupt body behind a good header
            payload = good.payload[:40] + self.rng.bytes(len(good.payload) - 40)
            return ImageMessage(good.seq, good.timestamp, "png", WIDTH, HEIGHT, payload).pack()
        if choice == 4:  # a float TIFF sent as png
            return _frame(self.seq + 1, self.time + 0.01, 2, WIDTH, HEIGHT, self.tiff)
        if choice == 5:  # a 20000x20000 PNG (its header)
            return _frame(self.seq + 1, self.time + 0.01, 2, WIDTH, HEIGHT, png_header_only(20000, 20000))
        if choice == 6:  # 16-bit PNG
            return _frame(self.seq + 1, self.time + 0.01, 2, WIDTH, HEIGHT, self.deep_png)
        if choice == 7:  # truncated
            data = good.pack()
            return data[: int(self.rng.integers(0, len(data)))]
        if choice == 8:  # a header that lies about its magic, version, encoding or length
            header = [{"magic": b"JPEG"}, {"version": 9}, {"length": len(good.payload) + 5}][int(self.rng.integers(3))]
            return _frame(good.seq, good.timestamp, 2, WIDTH, HEIGHT, good.payload, **header)
        if choice == 9:  # unknown encoding
            return _frame(good.seq, good.timestamp, 77, WIDTH, HEIGHT, good.payload)
        if choice == 10:  # random bytes
            return self.rng.bytes(int(self.rng.integers(0, 300)))
        if choice == 11:  # a timestamp of any magnitude
            return _frame(good.seq, float(self.rng.choice(HOSTILE_TIMES)), 2, WIDTH, HEIGHT, good.payload)
        return _frame(good.seq, good.timestamp, 2, 0 if self.rng.random() < 0.5 else 9000, HEIGHT, good.payload)  # impossible size

    def message(self) -> str | bytes:
        if self.rng.random() < 1.0 / self.bye_every:  # the session ends
            return '{"type": "bye"}'
        return self.frame() if self.rng.random() < 0.4 else self.text()


@dataclass
class FuzzResult:
    messages: int = 0
    text_messages: int = 0
    frames: int = 0
    sessions: int = 0
    raised: list[str] = field(default_factory=list)  # messages whose handling raised: a crash of the live server's connection
    internal_errors: int = 0  # the session's safety net caught a bug (an 'internal' error): a crash without it
    estimator_crashes: int = 0
    frames_refused: int = 0
    frames_estimated: int = 0
    unanswered: int = 0
    answered_twice: int = 0
    memory_growth_mb: float = 0.0
    seconds: float = 0.0

    @property
    def every_frame_answered_once(self) -> bool:
        return self.unanswered == 0 and self.answered_twice == 0

    @property
    def server_crashes(self) -> int:
        return len(self.raised) + self.internal_errors


def _rss_mb() -> float:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024.0
    return 0.0


def _frame_seq(data: bytes) -> int | None:
    try:
        return decode_image(data).seq
    except ProtocolError:
        return None


async def fuzz_station(data_dir: Path, messages: int, seed: int = 0, progress=None, bye_every: int = 5000, new_estimator_every: int = 2000) -> FuzzResult:
    """``messages`` hostile messages into a real station, in-process (the last one a bye); see the
    module's docstring. Each new session waits for its estimator, as a phone does."""
    settings = Settings.model_validate({"station": {"min_free_disk_mb": 0}})
    station = Station(data_dir, settings)
    await station.start()
    client = HostileClient(seed, bye_every, new_estimator_every)
    result = FuzzResult()
    replies: list = []  # during the current message
    answers: dict[int, int] = {}  # seq of each frame the current session took -> its answers so far
    session = None
    number = 0
    start = time.monotonic()
    baseline = None

    in_frame = False  # an error while a frame is handled is that frame's (a refused one may repeat a taken seq)

    def send(text: str) -> None:
        message = decode_text(text)
        replies.append(message)
        if message.type in ("pose", "dropped") or (message.type == "error" and message.seq is not None and not in_frame):
            if message.seq in answers:
                answers[message.seq] += 1
        result.internal_errors += message.type == "error" and message.code == "internal"

    def account() -> None:
        """The ended session's frames: each answered exactly once."""
        result.unanswered += sum(1 for count in answers.values() if count == 0)
        result.answered_twice += sum(1 for count in answers.values() if count > 1)
        result.frames_estimated += len(answers)
        answers.clear()

    async def open_session():
        nonlocal number
        number += 1
        result.sessions += 1
        opened, _ = station.open_session(Hello(protocol=PROTOCOL_VERSION, device=f"fuzz-{number}"))
        opened.attach(send)
        opened.on_text(json.dumps({"type": "config", "camera": CAMERA}), time.time())
        client.seq, client.time, client.telemetry_time = 0, 1.0, 1.0
        deadline = time.monotonic() + 120
        while not (opened.worker is not None and opened.worker.ready) and time.monotonic() < deadline:
            await asyncio.sleep(0.05)
        return opened

    try:
        session = await open_session()
        for index in range(messages):
            message = client.message() if index < messages - 1 else '{"type": "bye"}'
            replies.clear()
            before = 0
            next_seq = session.next_seq
            try:
                if isinstance(message, bytes):
                    result.frames += 1
                    seq = _frame_seq(message)
                    in_frame = True
                    session.on_binary(message, time.time())
                    in_frame = False
                    if seq is not None and session.next_seq == seq + 1 and next_seq <= seq:  # taken: answered now or later
                        answers[seq] = sum(1 for m in replies[before:] if m.type in ("pose", "dropped", "error") and getattr(m, "seq", None) == seq)
                    else:  # refused: one error, now (nothing else answers with an error during the call)
                        result.frames_refused += 1
                        mine = [m for m in replies[before:] if m.type == "error"]
                        result.unanswered += len(mine) == 0
                        result.answered_twice += len(mine) > 1
                else:
                    result.text_messages += 1
                    session.on_text(message, time.time())
            except Exception as exc:  # noqa: BLE001 - what the fuzzer is looking for
                in_frame = False
                result.raised.append(f"{exc.__class__.__name__}: {exc} <- {message[:80]!r}")
            result.messages += 1
            if session.ended:
                await station.end_session(session)
                session.detach(clean=True)
                account()
                if index < messages - 1:
                    session = await open_session()
            if index % 50 == 0:
                await asyncio.sleep(0)  # the estimators' answers come in
            if index == messages // 10:
                gc.collect()
                baseline = _rss_mb()
            if progress is not None and index % 1000 == 0:
                progress(index, messages)
        if not session.ended:
            await station.end_session(session)  # frames in flight get their answers
            session.detach(clean=True)
            account()
        gc.collect()
        result.memory_growth_mb = _rss_mb() - (baseline if baseline is not None else _rss_mb())
    finally:
        await station.stop()
    store = SessionStore(station.store.url)
    try:
        codes = [e["code"] for e in store.recent_events(limit=None)]
    finally:
        store.close()
    result.estimator_crashes = codes.count("estimator_restarted") + codes.count("estimator_failed")
    result.seconds = time.monotonic() - start
    return result
