"""One mobile station's session: checks each message, records it, feeds the estimator, answers.

Transport-free: the WebSocket handler passes messages in and gives it a ``send`` callable for the
replies (``None`` while the link is down; poses computed meanwhile are still recorded). Every
message is checked, then recorded, then handled: bad input is refused without filling the disk,
and a dropped link or a failing estimator never loses what was received. Every frame gets exactly
one answer (a pose, ``dropped`` or an error): the estimator process dying answers its frames in
flight with ``estimator_failed`` and a supervisor starts a new one.
"""

from __future__ import annotations

import asyncio
import json
import logging
import time
from collections import deque
from collections.abc import Callable
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Protocol

import numpy as np

from evp.config import Settings
from evp.runtime.estimator_process import EstimatorProcess, ProcessEvents
from evp.station.estimation import vision_main, worker_main
from evp.station.protocol import (
    Bye,
    Config,
    Dropped,
    Enable,
    Error,
    GpsTelemetry,
    ImageMessage,
    ImuBatchTelemetry,
    Log,
    Pose,
    ProtocolError,
    RangeTelemetry,
    Status,
    Telemetry,
    Velocity,
    check_image_header,
    decode_image,
    decode_text,
    encode,
    telemetry_records,
)
from evp.station.recording import SessionRecording
from evp.station.robot_link import RobotLink
from evp.station.store import SessionStore
from evp.types import CameraModel, EncoderCounts

if TYPE_CHECKING:
    from evp.station.marker_mission import MarkerMission

log = logging.getLogger(__name__)


class StationHooks(Protocol):
    """What a session tells the station (operator UI, MAVLink, estimator settings)."""

    settings: Settings

    def estimator_settings(self, session: LiveSession) -> tuple[str, str]: ...
    def on_pose(self, session: LiveSession, pose: Pose, latency_ms: float) -> None: ...
    def on_event(self, session: LiveSession, event: dict) -> None: ...
    def on_status(self, session: LiveSession) -> None: ...
    def on_new_map(self, session: LiveSession) -> None: ...
    def on_navigation(self, session: LiveSession, state: dict) -> None: ...
    def on_gps(self, session: LiveSession, fix: GpsTelemetry) -> None: ...
    def marker_mission(self, session: LiveSession) -> MarkerMission | None: ...
    def storage_problem(self) -> str | None: ...


@dataclass
class Counters:
    frames_received: int = 0
    frames_estimated: int = 0
    frames_dropped: int = 0
    latencies_ms: deque = field(default_factory=lambda: deque(maxlen=300))
    estimated_times: deque = field(default_factory=lambda: deque(maxlen=120))  # wall times of recent poses

    def fps(self, now: float) -> float:
        recent = [t for t in self.estimated_times if now - t <= 2.0]
        return (len(recent) - 1) / (recent[-1] - recent[0]) if len(recent) > 2 and recent[-1] > recent[0] else 0.0

    def latency_p50(self) -> float:
        return float(np.median(self.latencies_ms)) if self.latencies_ms else 0.0


class LiveSession:
    def __init__(self, session_id: str, device: str, store: SessionStore, recording_path: Path, station: StationHooks, estimating: bool = True):
        self.id = session_id
        self.device = device
        self.owner = ""  # the credential id that opened it (evp.station.auth)
        self.store = store
        self.station = station
        self.recording = SessionRecording(recording_path)
        self.recorded_bytes = recording_path.stat().st_size if recording_path.is_file() else 0  # against station.session_quota_bytes
        self.degraded = ""  # why this session runs a lighter estimator than configured, when it does
        self._estimator_start: asyncio.Task | None = None
        self._quota_told = False
        self.max_fps: float | None = None  # the overload governor's cap (evp.station.overload)
        self._accepted_at = -np.inf  # receive time of the last frame under that cap
        self._closed = False
        self.camera: CameraModel | None = None  # named after the device
        self.T_body_cam: list[float] | None = None  # the camera in the IMU frame (config), for the navigation stage
        self.answers = "at_once"
        self.navigation: dict | None = None  # the navigation stage's last reported state
        self.mission: MarkerMission | None = None  # the marker autopilot flying this vehicle (autopilot.vehicles)
        self.estimating = estimating
        self.worker: EstimatorProcess | None = None
        self.send: Callable[[str], None] | None = None
        self.counters = Counters()
        self.connected = False
        self.disconnected_at: float | None = None  # time.monotonic() when the link went down
        self.ended = False
        self._last_seq = -1
        self._last_frame_time = -np.inf
        self._last_telemetry_time: dict[str, float] = {}
        self._received_at: dict[int, float] = {}
        self._frames: dict[int, ImageMessage] = {}  # sent to the estimator, not answered yet
        self._telemetry_batch: list = []  # records for the estimator, sent with the next frame
        self._estimator_deaths = 0  # since the last pose or config (the supervisor's count)
        self.robot = RobotLink(station.settings.robot)  # a wheel robot's encoders and drive commands

    # --- link ---------------------------------------------------------------------------------

    @property
    def next_seq(self) -> int:
        return self._last_seq + 1

    def continue_from(self, frames: list[dict]) -> None:
        """Sequence and time order carried over from the recorded frames (resumed after a restart)."""
        if frames:
            self._last_seq = max(r["seq"] for r in frames)
            self._last_frame_time = max(r["timestamp"] for r in frames)
            self.counters.frames_received = len(frames)
            self.counters.frames_estimated = sum(1 for r in frames if r["estimated"])

    def attach(self, send: Callable[[str], None]) -> None:
        self.send = send
        self.connected = True
        self.disconnected_at = None
        self.store.update_session(self.id, status="live", ended_at=None)

    def detach(self, clean: bool) -> None:
        """The link closed: after ``bye`` the session has ended, otherwise it is interrupted."""
        self.send = None
        self.connected = False
        self.disconnected_at = time.monotonic()
        self.robot.link_lost()
        self.store.update_session(self.id, status="ended" if clean else "interrupted", ended_at=time.time(), **self.count_columns())
        self.event(
            "info" if clean else "warning",
            "ended" if clean else "interrupted",
            "session ended by the mobile station" if clean else "link lost: session interrupted (resume it by reconnecting)",
        )

    def reply(self, message) -> None:
        if self.send is not None:
            self.send(encode(message))

    def event(self, level: str, code: str, text: str) -> None:
        row = self.store.log_event(self.id, level, code, text)
        self.station.on_event(self, row)

    def refuse(self, error: ProtocolError) -> None:
        """Tell the client, log the event (storage_full once for the station, not per message
        into the store that cannot write); the session goes on."""
        self.reply(Error(code=error.code, message=error.message, seq=error.seq))
        if error.code == "storage_full":
            return
        self.event("error", error.code, error.message if error.seq is None else f"frame {error.seq}: {error.message}")

    # --- incoming -----------------------------------------------------------------------------

    def on_text(self, text: str, now: float) -> None:
        try:
            message = decode_text(text)
        except ProtocolError as exc:
            self.recording.text(text[:4096], now)  # kept (truncated) as evidence
            self.refuse(exc)
            return
        try:
            if not isinstance(message, Telemetry):  # telemetry is recorded once its order is checked
                self.recording.text(text, now)
            self._dispatch(message, text, now)
        except ProtocolError as exc:
            self.refuse(exc)
        except OSError as exc:  # the recording's disk
            self.refuse(ProtocolError("storage_full", f"{message.type} not recorded: {exc}"))
        except Exception as exc:  # a bug: the client hears of it, the session goes on
            log.exception("session %s: %s message failed", self.id, message.type)
            self.refuse(ProtocolError("internal", f"{message.type}: {exc.__class__.__name__}: {exc}"))

    def _dispatch(self, message, text: str, now: float) -> None:
        if isinstance(message, Telemetry):
            self._telemetry(message, text, now)
        elif isinstance(message, Config):
            self._config(message, now)
        elif isinstance(message, Enable):
            self.set_estimating(message.enabled, "mobile station")
        elif isinstance(message, Log):
            self.event(message.level if message.level != "debug" else "info", "mobile_log", message.text)
        elif isinstance(message, Bye):
            self.ended = True
        elif isinstance(message, Error):
            self.event("warning", "mobile_error", f"{message.code}: {message.message}")
        elif message.type == "hello":
            raise ProtocolError("malformed", "hello is only valid as the first message of a connection")
        else:
            raise ProtocolError("unknown_type", f"'{message.type}' is sent by the station, not to it")

    def _telemetry(self, message, text: str, now: float) -> None:
        sensor = "imu" if isinstance(message, ImuBatchTelemetry) else message.kind  # one IMU, sent a sample or a batch at a time
        first = message.samples[0][0] if isinstance(message, ImuBatchTelemetry) else message.timestamp
        last = self._last_telemetry_time.get(sensor, -np.inf)
        if first < last:
            raise ProtocolError("out_of_order", f"{message.kind} telemetry at t={first!r} is older than the last one (t={last!r})")
        problem = self.station.storage_problem()
        if problem:
            raise ProtocolError("storage_full", f"{message.kind} telemetry not recorded: {problem}")
        self._last_telemetry_time[sensor] = message.timestamp
        self.recording.telemetry(message, text, now)
        data = message.model_dump(exclude={"type", "kind", "timestamp"})
        self.store.insert("telemetry", session_id=self.id, kind=sensor, timestamp=message.timestamp, received_at=now, data_json=json.dumps(data))
        jump = self.station.settings.station.max_clock_jump_s
        if np.isfinite(last) and first - last > jump:
            self.event(
                "warning",
                "clock_jump",
                f"{message.kind} telemetry jumped {first - last:.1f} s ahead (more than {jump:g} s): the sensor's clock was reset?",
            )
        if isinstance(message, GpsTelemetry) and message.latitude_deg is not None:
            self.station.on_gps(self, message)  # the operator's plot: fused track against GPS
        if isinstance(message, RangeTelemetry) and self.mission is not None:
            self.mission.on_range(message.distance_m)
        records = telemetry_records(message)
        if isinstance(records[0], EncoderCounts):  # every reading, estimator or not: the next difference needs it
            record, warnings = self.robot.wheel_record(records[0])
            records = [record] if record is not None else []
            for text in warnings:
                self.event("warning", "encoder", text)
        if self.worker is not None:  # the estimator fuses them (the navigation filter), whether estimating or not
            self._telemetry_batch.extend(records)

    def drive(self, linear_m_s: float, angular_rad_s: float, now: float) -> Velocity:
        """Drive the robot: the command is recorded, sent now and repeated (:meth:`repeat_drive`)
        until another replaces it; zero stops it."""
        command = self.robot.drive(linear_m_s, angular_rad_s, now)
        self.recording.text(encode(command), now)
        self.reply(command)
        return command

    def repeat_drive(self, now: float) -> None:
        """Send the current command again when it is due (the station's drive loop calls this)."""
        command = self.robot.due(now)
        if command is not None:
            self.reply(command)

    def _config(self, message: Config, now: float) -> None:
        self._estimator_deaths = 0  # the mobile station's config restarts an estimator the supervisor gave up on
        self.store.insert("settings", session_id=self.id, t=now, source="mobile", data_json=encode(message))
        navigation = (message.T_body_cam or self.T_body_cam, message.answers or self.answers)
        changed = navigation != (self.T_body_cam, self.answers) or self.worker is None  # a config restarts a failed estimator
        self.T_body_cam, self.answers = navigation
        if message.camera is None or replace(message.camera, name=self.device or "mobile") == self.camera:
            if changed and self.camera is not None:
                self.event("info", "config", f"IMU extrinsic {'given' if self.T_body_cam else 'none'}, answers {self.answers}")
                self.restart_estimator()
            return
        camera = replace(message.camera, name=self.device or "mobile")
        self.recording.camera(camera, now)
        self.camera = camera
        if self.mission is not None:
            self.mission.set_camera(camera)
        else:
            self.mission = self.station.marker_mission(self)
        self.store.update_session(self.id, camera_json=json.dumps(asdict(camera)))
        self.event("info", "config", f"camera {camera.width}x{camera.height} fx={camera.fx:.1f} fy={camera.fy:.1f} cx={camera.cx:.1f} cy={camera.cy:.1f}")
        self.restart_estimator()

    def on_binary(self, data: bytes, now: float) -> None:
        """Checked (header, order, size, the image's own header, the disk), limited (the session's
        quota, the overload cap), recorded, then estimated: a frame refused or shed is neither
        recorded nor counted as received, and gets its error or its ``dropped``."""
        try:
            message = decode_image(data)
            self._check_frame(message)
            problem = self.station.storage_problem()
            if problem:
                raise ProtocolError("storage_full", f"frame not recorded: {problem}", message.seq)
        except ProtocolError as exc:
            self.refuse(exc)
            return
        if self.recorded_bytes + len(data) > self.station.settings.station.session_quota_bytes:
            self._over_quota(message)
            return
        if self.max_fps is not None and now - self._accepted_at < 0.9 / self.max_fps:  # shed before it costs anything
            self._drop(message, "overload")
            return
        try:
            self.recording.image(message, now)
        except OSError as exc:  # the recording's disk
            self.refuse(ProtocolError("storage_full", f"frame not recorded: {exc}", message.seq))
            return
        self._accepted_at = now
        self.recorded_bytes += len(data)
        self.counters.frames_received += 1
        self._last_seq, self._last_frame_time = message.seq, message.timestamp
        if self.mission is not None:  # the autopilot flies on every recorded frame, estimated or not
            self._fly(message)
        if self.camera is None or not self.estimating or self.worker is None:
            self._frame_row(message, now, estimated=False)
            if self.estimator_given_up:
                self.refuse(ProtocolError("estimator_failed", "the estimator is down (it kept failing); send a config to start a new one", message.seq))
            else:
                self._drop(message, "not_configured" if self.camera is None else "estimation_off")
            return
        self._received_at[message.seq] = now
        self._frames[message.seq] = message
        self._send_telemetry()
        self.worker.submit(message)

    def _fly(self, message: ImageMessage) -> None:
        """The marker autopilot's step; a failure in it (a bug) is the operator's error event, and
        the frame still gets its answer (the flight controller's own timeout holds the vehicle)."""
        try:
            self.mission.on_frame(message)
        except Exception as exc:
            log.exception("session %s: marker autopilot failed on frame %d", self.id, message.seq)
            self.event("error", "autopilot_failed", f"frame {message.seq}: {exc.__class__.__name__}: {exc}")

    def _over_quota(self, message: ImageMessage) -> None:
        """Refused, not recorded: the operator hears it once, the phone for every frame."""
        quota = self.station.settings.station.session_quota_bytes
        error = ProtocolError("busy", f"this session's recording reached its quota of {quota / 2**20:.0f} MiB (station.session_quota_bytes)", message.seq)
        if not self._quota_told:
            self._quota_told = True
            self.refuse(error)
        else:
            self.reply(Error(code=error.code, message=error.message, seq=error.seq))
        self.counters.frames_dropped += 1

    def _send_telemetry(self) -> None:
        """The telemetry since the last frame, in one message: the estimator process's link thread
        handles 30 messages a second instead of 250 (each one waits for the GIL while SLAM holds it)."""
        if self._telemetry_batch and self.worker is not None:
            self.worker.send_side(("telemetry", self._telemetry_batch))
        self._telemetry_batch = []

    def _check_frame(self, message: ImageMessage) -> None:
        if message.seq <= self._last_seq:
            raise ProtocolError("out_of_order", f"sequence number {message.seq} after {self._last_seq}", message.seq)
        if message.timestamp <= self._last_frame_time:
            raise ProtocolError("out_of_order", f"timestamp {message.timestamp!r} is not after the previous frame's {self._last_frame_time!r}", message.seq)
        if self.camera is not None and (message.width, message.height) != (self.camera.width, self.camera.height):
            raise ProtocolError(
                "malformed", f"image is {message.width}x{message.height}, the configured camera is {self.camera.width}x{self.camera.height}", message.seq
            )
        check_image_header(message)

    def _frame_row(self, message: ImageMessage, received_at: float, estimated: bool) -> None:
        self.store.insert(
            "frames",
            session_id=self.id,
            seq=message.seq,
            timestamp=message.timestamp,
            received_at=received_at,
            encoding=message.encoding,
            width=message.width,
            height=message.height,
            size_bytes=len(message.payload),
            estimated=estimated,
        )

    def _drop(self, message: ImageMessage, reason: str) -> None:
        self.counters.frames_dropped += 1
        self.reply(Dropped(seq=message.seq, reason=reason))

    # --- estimator ----------------------------------------------------------------------------

    def restart_estimator(self) -> None:
        """A fresh estimator (new map) for the current camera. One process per session, ever: the
        new one starts once the old one has finished (its frame in flight answered); configs that
        arrive meanwhile change what it starts with, not how many start."""
        old, self.worker = self.worker, None
        if self._estimator_start is not None and not self._estimator_start.done():
            return  # the start under way reads the newest camera and settings when it gets there
        if old is None:
            self._start_estimator()
        else:
            self._estimator_start = asyncio.get_running_loop().create_task(self._replace_estimator(old))
            self.reply(Status(state="starting", estimating=self.estimating, message="estimator restarting"))

    async def _replace_estimator(self, old: EstimatorProcess) -> None:
        await old.close()
        if self.worker is None:
            self._start_estimator()

    def _start_estimator(self) -> None:
        if self.camera is None or self._closed:  # nothing to estimate, or the session ended meanwhile
            return
        settings_json, self.degraded = self.station.estimator_settings(self)
        self.store.insert("settings", session_id=self.id, t=time.time(), source="server", data_json=settings_json)
        events = ProcessEvents(self._worker_ready, self._worker_pose, self._worker_error, self._worker_dropped, self._worker_exit, self._worker_report)
        args = (self.camera, settings_json, self.T_body_cam, self.answers)
        placement = self.station.settings.station
        vision = (vision_main, (self.camera, settings_json, self.T_body_cam)) if placement.vision_process and not placement.cluster else None
        self.worker = EstimatorProcess(worker_main, args, events, every_message=self.answers == "at_once", partner=vision)
        self.station.on_new_map(self)
        if self.degraded:
            self.event("warning", "degraded", self.degraded)
        self.reply(Status(state="starting", estimating=self.estimating, message=self.degraded or "estimator starting"))

    def set_estimating(self, enabled: bool, by: str) -> None:
        if enabled == self.estimating:
            return
        self.estimating = enabled
        self.event("info", "enable" if enabled else "disable", f"estimation {'enabled' if enabled else 'disabled'} by the {by}")
        self.reply(Enable(enabled=enabled))
        self.station.on_status(self)

    def _worker_ready(self) -> None:
        self.event("info", "estimator_ready", "estimator ready")
        self.reply(self.status())
        self.station.on_status(self)

    def _take(self, seq: int | None) -> tuple[ImageMessage, float] | None:
        """A frame in flight, taken to be answered: each is taken once, so answered once."""
        if seq is None or seq not in self._frames:
            return None
        return self._frames.pop(seq), self._received_at.pop(seq)

    def _worker_pose(self, pose: Pose) -> None:
        now = time.time()
        taken = self._take(pose.seq)
        if taken is None:  # already answered (its estimator was replaced meanwhile)
            return
        message, received_at = taken
        self._estimator_deaths = 0
        latency_ms = (now - received_at) * 1000.0
        self._frame_row(message, received_at, estimated=True)
        self.counters.frames_estimated += 1
        self.counters.latencies_ms.append(latency_ms)
        self.counters.estimated_times.append(now)
        self.reply(pose)
        try:
            self.recording.pose(pose, now)
        except OSError as exc:  # the pose is in the database; the operator hears of the disk
            self.event("error", "storage_full", f"pose {pose.seq} not in the recording: {exc}")
        t, q = pose.t, pose.q
        self.store.insert(
            "poses", session_id=self.id, seq=pose.seq, timestamp=pose.timestamp, tx=t[0], ty=t[1], tz=t[2], qw=q[0], qx=q[1], qy=q[2], qz=q[3],
            state=pose.state, quality=pose.quality, reset_counter=pose.reset_counter, processing_ms=pose.processing_ms, latency_ms=latency_ms,
        )  # fmt: skip
        self.station.on_pose(self, pose, latency_ms)

    def _worker_report(self, kind: str, payload) -> None:
        """The navigation stage's notices become events (GPS alarms, IMU problems), its state goes
        to the operators."""
        if kind == "notice":
            level, code, text = payload
            self.event(level, code, text)
        elif kind == "navigation":
            self.navigation = payload
            self.station.on_navigation(self, payload)

    def _worker_error(self, code: str, text: str, seq: int | None) -> None:
        taken = self._take(seq)
        if taken is not None:
            self._frame_row(*taken, estimated=False)
        if seq is None or taken is not None:
            self.refuse(ProtocolError(code, text, seq))

    def _worker_dropped(self, message: ImageMessage) -> None:
        taken = self._take(message.seq)
        if taken is not None:
            self._frame_row(*taken, estimated=False)
            self._drop(message, "stale")

    def _worker_exit(self, reason: str) -> None:
        """The supervisor: the frames in flight get their error, the operator an event, and a new
        estimator (a new map) starts, unless it keeps dying without a pose in between."""
        self.worker = None
        for seq in sorted(self._frames):
            message, received_at = self._take(seq)
            self._frame_row(message, received_at, estimated=False)
            self.reply(Error(code="estimator_failed", message=f"{reason} on this frame; a new estimator is starting", seq=seq))
        self._estimator_deaths += 1
        limit = self.station.settings.station.max_estimator_restarts
        if self._estimator_deaths > limit:
            self.event("error", "estimator_failed", f"{reason}, {self._estimator_deaths} times without a pose: left down; a config starts a new one")
            self.reply(self.status())
            self.station.on_status(self)
            return
        self.event("error", "estimator_restarted", f"{reason}: restarted with a new map ({self._estimator_deaths} of {limit} restarts)")
        self.restart_estimator()

    @property
    def estimator_given_up(self) -> bool:
        """The supervisor left the estimator down (it kept dying without a pose); a config restarts it."""
        return self.worker is None and self._estimator_deaths > self.station.settings.station.max_estimator_restarts

    # --- status -------------------------------------------------------------------------------

    def status(self) -> Status:
        if self.camera is None:
            state = "waiting_config"
        elif self.estimator_given_up:
            state = "failed"
        elif self.worker is None or not self.worker.ready:
            state = "starting"
        else:
            state = "running" if self.estimating else "stopped"
        c = self.counters
        return Status(
            state=state,
            estimating=self.estimating,
            frames_received=c.frames_received,
            frames_estimated=c.frames_estimated,
            frames_dropped=c.frames_dropped,
            fps=round(c.fps(time.time()), 2),
            latency_ms_p50=round(c.latency_p50(), 2),
            message=self.station.storage_problem() or self.degraded,
        )

    def count_columns(self) -> dict:
        c = self.counters
        return {"frames_received": c.frames_received, "frames_estimated": c.frames_estimated, "frames_dropped": c.frames_dropped}

    async def close(self, status: str) -> None:
        """Finish the estimator (frames in flight get their poses recorded) and the recording
        (compacted: chunked, compressed, indexed)."""
        self._closed = True
        self._send_telemetry()
        if self._estimator_start is not None:
            await self._estimator_start  # a replacement under way finishes (or starts nothing once ended)
        if self.worker is not None:
            await self.worker.close()
            self.worker = None
        await asyncio.to_thread(self.recording.close)
        self.store.update_session(self.id, status=status, ended_at=time.time(), **self.count_columns())
