"""``evp stream``: a mobile station in Python (companion computers, tests, benchmarks).

Paced at the recorded rate (``realtime``), as a phone, each frame is answered at once with the
station's current estimate (``answers: at_once``) and vision takes the newest frame it can. As
fast as possible, at most ``max_in_flight`` frames are unanswered at a time and each is answered
after the estimator (``answers: after_vision``), so the station estimates every frame and the
trajectory equals ``evp run``'s. A dataset with an IMU and its camera extrinsic sends the
extrinsic, so the station fuses the telemetry as ``evp run`` does.

A frame's sequence number is its index in the source, so ``--resume`` continues where the station
stopped taking them (the welcome's ``next_seq``): the frames before it, and the telemetry before
the first frame sent, are skipped, not sent again to be refused.
"""

from __future__ import annotations

import asyncio
import contextlib
import ssl
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from urllib.parse import urlsplit, urlunsplit

import numpy as np

from evp.errors import LinkError
from evp.mobile.sources import StreamSource, telemetry_message
from evp.station.protocol import (
    MAX_IMU_BATCH,
    PROTOCOL_VERSION,
    Bye,
    Config,
    Dropped,
    Enable,
    Error,
    Hello,
    ImuBatchTelemetry,
    Pose,
    ProtocolError,
    Status,
    Velocity,
    Welcome,
    decode_text,
    encode,
    encode_image,
)
from evp.types import Frame, ImuSample, TrackingState

READY_TIMEOUT_S = 120.0
# IMU samples go together, one imu_batch per frame period (they are sent before each frame) and
# at most this long apart without frames: a message per 200-400 Hz sample was most of the
# station's event loop (docs/decisions.md), and 50 ms is well inside the filter's buffered horizon.
IMU_BATCH_SPAN_S = 0.05
DRAIN_TIMEOUT_S = 60.0


class StreamError(LinkError):
    """The station refused the stream or the link failed."""


def mobile_url(url: str) -> str:
    """ws(s):// URL of the mobile endpoint from what a user types (http(s)/ws(s), path optional)."""
    parts = urlsplit(url if "://" in url else f"wss://{url}")
    scheme = {"http": "ws", "https": "wss"}.get(parts.scheme, parts.scheme)
    if scheme not in ("ws", "wss"):
        raise StreamError(f"{url}: the station URL must be ws://, wss://, http:// or https://")
    path = parts.path if parts.path not in ("", "/") else "/ws/mobile"
    return urlunsplit((scheme, parts.netloc, path, parts.query, ""))


def tls_context(cafile: str | None, accept_any: bool) -> ssl.SSLContext:
    """The station's certificate is verified: against ``cafile`` (its cert.pem, self-signed) when
    given, else against the system's authorities (a station behind a proxy with a public
    certificate). ``accept_any`` (a pinned fingerprint, checked once connected, or --insecure)
    takes any certificate here."""
    if accept_any:
        context = ssl.SSLContext(ssl.PROTOCOL_TLS_CLIENT)
        context.check_hostname = False
        context.verify_mode = ssl.CERT_NONE
        return context
    context = ssl.create_default_context(cafile=cafile)
    if cafile:
        context.check_hostname = False  # the station's certificate names its addresses, not DNS names users type
        context.verify_flags |= ssl.VERIFY_X509_PARTIAL_CHAIN  # the self-signed leaf is its own trust anchor
    return context


@dataclass
class StreamReport:
    session_id: str = ""
    frames_sent: int = 0
    frames_skipped: int = 0  # resumed: frames the station already had
    frames_refused: int = 0  # answered with an error
    telemetry_sent: int = 0
    velocity_commands: int = 0  # drive commands the station sent (a wheel robot)
    poses: dict[int, Pose] = field(default_factory=dict)
    dropped: dict[int, str] = field(default_factory=dict)
    errors: list[str] = field(default_factory=list)
    sent_at: dict[int, float] = field(default_factory=dict)
    latency_ms: dict[int, float] = field(default_factory=dict)
    fingerprint: str | None = None
    duration_s: float = 0.0

    def summary(self) -> dict:
        latencies = np.array(list(self.latency_ms.values())) if self.latency_ms else np.zeros(1)
        tracked = sum(1 for p in self.poses.values() if TrackingState(p.state).tracked)
        return {
            "session_id": self.session_id,
            "frames_sent": self.frames_sent,
            "frames_skipped": self.frames_skipped,
            "frames_refused": self.frames_refused,
            "telemetry_sent": self.telemetry_sent,
            "velocity_commands": self.velocity_commands,
            "poses_received": len(self.poses),
            "poses_tracked": tracked,
            "frames_dropped": len(self.dropped),
            "errors": len(self.errors),
            "first_errors": self.errors[:5],
            "latency_ms_p50": round(float(np.percentile(latencies, 50)), 2),
            "latency_ms_p95": round(float(np.percentile(latencies, 95)), 2),
            "duration_s": round(self.duration_s, 3),
            "tls_fingerprint_sha256": self.fingerprint,
        }


class StreamClient:
    def __init__(
        self,
        url: str,
        token: str = "",
        device: str = "evp-stream",
        cafile: str | None = None,
        fingerprint: str | None = None,
        insecure: bool = False,
        on_pose: Callable[[Pose], None] | None = None,
        log: Callable[[str], None] | None = None,
        on_velocity: Callable[[Velocity], None] | None = None,
    ):
        self.url = mobile_url(url)
        self.token = token
        self.device = device
        self.cafile = cafile
        self.pin = fingerprint.upper() if fingerprint else None
        self.insecure = insecure
        self.on_pose = on_pose
        self.on_velocity = on_velocity  # a wheel robot's drive (evp.mobile.robot.VelocityWatchdog.command)
        self.log = log or (lambda text: print(text, file=sys.stderr))
        self.report = StreamReport()
        self._answered = asyncio.Event()
        self._ready = asyncio.Event()
        self._in_flight: set[int] = set()
        self._first_seq = 0

    async def _connect(self):
        import websockets
        import websockets.exceptions  # loaded lazily by websockets: the except clause below needs it before any connect

        try:
            context = tls_context(self.cafile, self.insecure or bool(self.pin)) if self.url.startswith("wss") else None
            return await websockets.connect(self.url, ssl=context, max_size=2**25, open_timeout=20)
        except ssl.SSLCertVerificationError as exc:
            raise StreamError(
                f"{self.url}: the station's certificate is not trusted ({exc.verify_message}); give its cert.pem (--cafile), "
                "its fingerprint from the operator page or QR code (--fingerprint), or --insecure"
            ) from exc
        except (OSError, websockets.exceptions.InvalidHandshake, websockets.exceptions.InvalidMessage, ssl.SSLError, TimeoutError) as exc:
            if self.url.startswith("ws://"):
                self.log(f"{self.url}: no plain WebSocket there ({exc.__class__.__name__}); trying TLS")
                self.url = "wss://" + self.url[len("ws://") :]
                return await self._connect()
            raise StreamError(f"cannot connect to {self.url}: {exc}") from exc

    def _check_certificate(self, connection) -> None:
        from evp.station.tls import der_fingerprint

        ssl_object = connection.transport.get_extra_info("ssl_object")
        if ssl_object is None:
            return
        self.report.fingerprint = der_fingerprint(ssl_object.getpeercert(binary_form=True))
        if self.pin and self.report.fingerprint != self.pin:
            raise StreamError(f"the station's certificate {self.report.fingerprint} is not the pinned {self.pin}")
        if self.insecure and not self.pin:
            self.log(f"--insecure: station certificate SHA-256 {self.report.fingerprint} not verified (pin it with --fingerprint)")

    async def run(
        self, source: StreamSource, realtime: bool, encoding: str, jpeg_quality: int = 90, resume: str | None = None, max_in_flight: int = 2
    ) -> StreamReport:
        start = time.monotonic()
        connection = await self._connect()
        try:
            self._check_certificate(connection)
            await connection.send(encode(Hello(protocol=PROTOCOL_VERSION, token=self.token, device=self.device, resume=resume)))
            welcome = decode_text(await asyncio.wait_for(connection.recv(), 20))
            if isinstance(welcome, Error):
                raise StreamError(f"station refused the stream: {welcome.code}: {welcome.message}")
            if not isinstance(welcome, Welcome):
                raise StreamError(f"expected welcome, got {welcome.type}")
            self.report.session_id = welcome.session_id
            self._first_seq = welcome.next_seq  # a resumed session continues its numbering
            receiver = asyncio.create_task(self._receive(connection))
            extrinsic = None if source.T_body_cam is None else [float(v) for v in np.asarray(source.T_body_cam).reshape(-1)]
            answers = "at_once" if realtime else "after_vision"  # as fast as possible: every frame estimated, as evp run
            await connection.send(
                encode(Config(camera=source.camera, fps=source.fps, encoding=encoding, color_space="bgr", T_body_cam=extrinsic, answers=answers))
            )
            try:
                await asyncio.wait_for(self._ready.wait(), READY_TIMEOUT_S)
            except TimeoutError:
                self.log(f"the station's estimator was not ready within {READY_TIMEOUT_S:.0f} s; streaming anyway")
            await self._send_items(connection, source, realtime, encoding, jpeg_quality, max_in_flight, receiver)
            await self._drain(receiver)
            await connection.send(encode(Bye()))
            receiver.cancel()
        finally:
            await connection.close()
            self.report.duration_s = time.monotonic() - start
        return self.report

    async def _send_items(
        self, connection, source: StreamSource, realtime: bool, encoding: str, jpeg_quality: int, max_in_flight: int, receiver: asyncio.Task
    ) -> None:
        pace_start: float | None = None
        frame_index = 0
        imu: list[ImuSample] = []  # samples waiting to go as one imu_batch (IMU_BATCH_SPAN_S)
        for item in source.items:
            if receiver.done():
                receiver.result()  # re-raises the link failure
                raise StreamError("the station closed the connection")
            if frame_index < self._first_seq:  # resumed: the station has these
                if isinstance(item, Frame):
                    frame_index += 1
                    self.report.frames_skipped += 1
                continue
            if isinstance(item, ImuSample):
                imu.append(item)
                if item.timestamp - imu[0].timestamp < IMU_BATCH_SPAN_S and len(imu) < MAX_IMU_BATCH:
                    continue
            if realtime and not source.live:
                now = time.monotonic()
                if pace_start is None:
                    pace_start = now - item.timestamp
                await asyncio.sleep(max(0.0, pace_start + item.timestamp - now))
            if imu:  # before what follows them in time: a frame's answer fuses the IMU up to it
                await self._send_imu(connection, imu)
                imu = []
            if isinstance(item, Frame):
                while not realtime and len(self._in_flight) >= max_in_flight and not receiver.done():
                    self._answered.clear()
                    answered = asyncio.create_task(self._answered.wait())
                    await asyncio.wait([receiver, answered], return_when=asyncio.FIRST_COMPLETED)
                    answered.cancel()
                message = await asyncio.to_thread(encode_image, item.image, frame_index, item.timestamp, encoding, jpeg_quality)
                frame_index += 1
                self._in_flight.add(message.seq)
                self.report.sent_at[message.seq] = time.monotonic()
                await connection.send(message.pack())
                self.report.frames_sent += 1
            elif not isinstance(item, ImuSample):
                telemetry = telemetry_message(item)
                if telemetry is not None:
                    await connection.send(encode(telemetry))
                    self.report.telemetry_sent += 1
        if imu:
            await self._send_imu(connection, imu)
        for problem in source.skipped:
            self.report.errors.append(f"source: {problem}")

    async def _send_imu(self, connection, samples: list[ImuSample]) -> None:
        rows = [[s.timestamp, *s.angular_velocity_rad_s, *s.linear_acceleration_m_s2] for s in samples]
        await connection.send(encode(ImuBatchTelemetry(timestamp=samples[-1].timestamp, samples=rows)))
        self.report.telemetry_sent += len(samples)

    async def _drain(self, receiver: asyncio.Task) -> None:
        deadline = time.monotonic() + DRAIN_TIMEOUT_S
        while self._in_flight and not receiver.done() and time.monotonic() < deadline:
            self._answered.clear()
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(self._answered.wait(), 0.5)

    def _resolve(self, seq: int | None) -> None:
        if seq is not None:
            self._in_flight.discard(seq)
        self._answered.set()

    async def _receive(self, connection) -> None:
        import websockets

        try:
            async for text in connection:
                try:
                    message = decode_text(text)
                except ProtocolError as exc:
                    self.report.errors.append(f"undecodable reply: {exc}")
                    continue
                self._handle(message)
        except websockets.exceptions.ConnectionClosedError as exc:
            raise StreamError(f"link lost: {exc}") from exc
        finally:
            self._answered.set()

    def _handle(self, message) -> None:
        now = time.monotonic()
        if isinstance(message, Pose):
            self.report.poses[message.seq] = message
            if message.seq in self.report.sent_at:
                self.report.latency_ms[message.seq] = (now - self.report.sent_at[message.seq]) * 1000.0
            self._resolve(message.seq)
            if self.on_pose:
                self.on_pose(message)
        elif isinstance(message, Dropped):
            self.report.dropped[message.seq] = message.reason
            self._resolve(message.seq)
        elif isinstance(message, Error):
            self.report.errors.append(f"{message.code}: {message.message}")
            self.report.frames_refused += message.seq is not None
            self.log(f"station error: {message.code}: {message.message}")
            self._resolve(message.seq)
        elif isinstance(message, Status):
            if message.state in ("running", "stopped", "failed"):
                self._ready.set()
        elif isinstance(message, Velocity):
            self.report.velocity_commands += 1
            if self.on_velocity:
                self.on_velocity(message)
        elif isinstance(message, Enable):
            self.log(f"estimation {'enabled' if message.enabled else 'disabled'} by the station")
