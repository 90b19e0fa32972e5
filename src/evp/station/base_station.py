"""The base station's state: settings, sessions, operators, recording store and MAVLink output.

The web layer (``evp.station.server``) only translates HTTP and WebSocket traffic into calls here.
"""

from __future__ import annotations

import asyncio
import json
import logging
import os
import time
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING

from evp import __version__
from evp.config import Settings
from evp.station.auth import DEV, Credentials, Identity
from evp.station.limits import FailureThrottle
from evp.station.overload import LoadGovernor
from evp.station.protocol import PROTOCOL_VERSION, SESSION_ID, Config, GpsTelemetry, Hello, Pose, ProtocolError
from evp.station.recording import has_summary, repair
from evp.station.session import LiveSession
from evp.station.storage import StorageGuard
from evp.station.store import SessionStore

if TYPE_CHECKING:
    from evp.station.marker_mission import MarkerMission
    from evp.station.mavlink_routes import MavlinkRoutes
from evp.types import CameraModel

log = logging.getLogger(__name__)
RESUME_FLUSH_S = 1.0


def default_camera(settings: Settings) -> CameraModel:
    """The camera the operator starts from: the settings' calibration, else seed 000's phone."""
    from evp.calib.profiles import configured_camera, load_profile

    return configured_camera(settings.camera) or load_profile("nexus5x_640x380")


class Station:
    def __init__(self, data_dir: Path, settings: Settings, db_url: str | None = None, mavlink_url: str | None = None):
        self.data_dir = Path(data_dir)
        self.data_dir.mkdir(parents=True, exist_ok=True)
        self.data_dir.chmod(0o700)  # recordings, database and key: the station's user only
        self.settings = settings
        self.camera = default_camera(settings)
        self.store = SessionStore(db_url or f"sqlite:///{(self.data_dir / 'evp.sqlite').resolve()}")
        self.storage = StorageGuard(self.data_dir, settings.station.min_free_disk_mb, lambda: self.store.problem)
        self._storage_failing = False  # what the operators were last told
        self.credentials = Credentials(self.store.engine)
        self.pairing_failures = FailureThrottle(settings.station.pairing_max_failures, settings.station.pairing_failure_window_s)
        self.link_closers: dict[str, Callable[[], None]] = {}  # session id -> close its current link (a resume by its owner)
        self.sessions: dict[str, LiveSession] = {}
        self.operators: set[asyncio.Queue] = set()
        self.link: dict = {}
        self.mavlink: MavlinkRoutes | None = None
        self.mavlink_url = mavlink_url
        self._generations: dict[str, int] = {}
        self._full: set[str] = set()  # sessions whose estimator is the configured one (not degraded)
        self.governor = LoadGovernor(settings.station)
        self._frames_counted: dict[str, int] = {}  # frames received per session at the last tick
        self._status_task: asyncio.Task | None = None
        self._drive_task: asyncio.Task | None = None
        self._watchdog_task: asyncio.Task | None = None

    # --- lifecycle ------------------------------------------------------------------------------

    async def start(self) -> None:
        """Recover what a station that stopped abruptly left behind, then start the outputs."""
        loop = asyncio.get_running_loop()
        self.store.on_problem = lambda _text: loop.call_soon_threadsafe(self.check_storage)  # from the writer's thread
        for session_id in self.store.mark_live_sessions_interrupted():
            self.store.log_event(session_id, "warning", "interrupted", "the station stopped during this session")
        for row in self.store.list_sessions(limit=None, status="interrupted"):  # an ended session's recording is always closed
            path = Path(row["mcap_path"] or "")
            leftover = path.with_suffix(".mcap.old")
            if leftover.exists() and not path.exists():
                leftover.replace(path)
            path.with_suffix(".mcap.tmp").unlink(missing_ok=True)  # a compaction cut short: the journal is intact
            if path.is_file() and not has_summary(path):
                kept = await asyncio.to_thread(repair, path)
                self.store.log_event(row["id"], "warning", "recording_repaired", f"{path.name}: closed after an abrupt stop ({kept} messages kept)")
        if self.mavlink_url or self.settings.mavlink.vehicles:
            from evp.station.mavlink_routes import MavlinkRoutes

            loop = asyncio.get_running_loop()

            def problem(session_id: str, text: str) -> None:  # from an output's thread
                loop.call_soon_threadsafe(self._mavlink_problem, session_id, text)

            self.mavlink = MavlinkRoutes(self.mavlink_url, self.settings.mavlink, problem)
        self._status_task = asyncio.get_running_loop().create_task(self._status_loop())
        self._drive_task = asyncio.get_running_loop().create_task(self._drive_loop())
        if self.settings.autopilot.vehicles:
            self._watchdog_task = asyncio.get_running_loop().create_task(self._watchdog_loop())
        self.store.log_event(None, "info", "started", f"station {__version__} started, data in {self.data_dir}")

    async def stop(self) -> None:
        for task in (self._status_task, self._drive_task, self._watchdog_task):
            if task is not None:
                task.cancel()
        for session in list(self.sessions.values()):
            await session.close("ended" if session.ended else "interrupted")
        self.sessions.clear()
        if self.mavlink is not None:
            self.mavlink.close()
        self.store.log_event(None, "info", "stopped", "station stopped")
        self.store.close()

    # --- mobile stations ------------------------------------------------------------------------

    def check_hello(self, hello: Hello) -> Identity:
        """The mobile station a hello comes from (blocking: a database read; call from a thread)."""
        if hello.protocol != PROTOCOL_VERSION:
            raise ProtocolError("bad_version", f"client speaks protocol {hello.protocol}, this station speaks {PROTOCOL_VERSION}")
        if self.settings.station.dev_loopback:
            return DEV
        identity = self.credentials.identify(hello.token) if hello.token else None
        if identity is None or not identity.may("mobile"):
            raise ProtocolError("bad_token", "this station needs the credential this device got when it paired (scan the station's QR code)")
        return identity

    def open_session(self, hello: Hello, identity: Identity) -> tuple[LiveSession, bool]:
        """A new session, or the one ``hello.resume`` names (kept in memory or reopened from disk)
        when ``identity`` opened it; refused while the station cannot record."""
        problem = self.storage_problem()
        if problem:
            raise ProtocolError("storage_full", problem)
        if hello.resume:
            return self._resume(hello, identity), True
        self._make_room()
        recordings = self.data_dir / "sessions"
        session_id = self.store.create_session(hello.device, "", identity.credential_id)
        path = recordings / f"{session_id}.mcap"
        self.store.update_session(session_id, mcap_path=str(path.resolve()))
        session = self._session(session_id, hello.device, path, identity.credential_id)
        self.sessions[session_id] = session
        session.event("info", "connected", f"mobile station {hello.device or '(unnamed)'} connected (credential {identity.credential_id or 'none'})")
        return session, False

    def _resume(self, hello: Hello, identity: Identity) -> LiveSession:
        """The session to resume: another device gets the same answer as for a session that does
        not exist, and an ended session is final. A resume while the old link still looks up (it
        died without a close) closes that link: the phone is back at once."""
        if not SESSION_ID.fullmatch(hello.resume):
            raise ProtocolError("unknown_session", f"{hello.resume[:64]!r} is not a session id (YYYYMMDD-HHMMSS-xxxxxx)")
        session = self.sessions.get(hello.resume)
        if session is None:  # the session's end may still be queued: its row must say so. On the event
            # loop: a working database commits within ~0.1 s; a failing one is waited for no longer
            # than RESUME_FLUSH_S (the row is then read as it stands, as before the flush existed)
            self.store.flush(RESUME_FLUSH_S)
        row = self.store.session(hello.resume) if session is None else None
        owner = session.owner if session is not None else (row or {}).get("owner")
        if owner is None or owner != identity.credential_id:
            raise ProtocolError("unknown_session", f"no session {hello.resume!r} of this device to resume")
        if session is None:
            if row["status"] in ("ended", "failed"):
                raise ProtocolError("session_ended", f"session {hello.resume} {row['status']}; ended sessions are final: start a new one")
            self._make_room()
            session = self._session(row["id"], row["device"], Path(row["mcap_path"]), owner)
            session.continue_from(self.store.rows("frames", session.id))
            self.sessions[session.id] = session
        if session.ended:
            raise ProtocolError("session_ended", f"session {hello.resume} ended; ended sessions are final: start a new one")
        if session.connected:
            self.link_closers.pop(session.id, lambda: None)()
            session.detach(clean=False)
        session.event("info", "resumed", f"session resumed by {hello.device or 'a mobile station'} (credential {identity.credential_id or 'none'})")
        return session

    def _session(self, session_id: str, device: str, path: Path, owner: str) -> LiveSession:
        """The session with its recording open; one whose file cannot be opened is marked failed
        (never shown live) and refused with storage_full."""
        try:
            session = LiveSession(session_id, device, self.store, path, self, self.settings.station.estimate_on_connect)
        except OSError as exc:
            self.store.update_session(session_id, status="failed", ended_at=time.time())
            self.on_event(None, self.store.log_event(session_id, "error", "storage_full", f"recording {path.name} cannot be opened: {exc}"))
            raise ProtocolError("storage_full", f"the recording cannot be opened: {exc.strerror or exc}") from None
        session.owner = owner
        return session

    def _make_room(self) -> None:
        """At ``station.max_sessions``: release the interrupted session that waited longest, else refuse."""
        cap = self.settings.station.max_sessions
        if len(self.sessions) < cap:
            return
        waiting = [s for s in self.sessions.values() if not s.connected and s.disconnected_at is not None]
        if not waiting:
            raise ProtocolError("busy", f"the station has {cap} live sessions (station.max_sessions); try again later")
        oldest = min(waiting, key=lambda s: s.disconnected_at)
        asyncio.get_running_loop().create_task(self._release(oldest, f"released to make room for a new session ({cap} at most)"))
        self.sessions.pop(oldest.id, None)

    def full_estimator_slots(self) -> int:
        """Sessions that may run the configured estimator at once; beyond, the light VO."""
        configured = self.settings.station.full_estimators
        return configured if configured is not None else len(os.sched_getaffinity(0))

    async def end_session(self, session: LiveSession) -> None:
        await session.close("ended")
        self.sessions.pop(session.id, None)
        self._full.discard(session.id)
        if self.mavlink is not None:
            self.mavlink.release(session.id)
        self.broadcast({"type": "sessions"})

    def config_for_mobile(self) -> Config:
        """What the operator's settings ask of a phone (camera, rate, colour, encoding, ORB)."""
        s = self.settings
        return Config(
            camera=self.camera,
            fps=s.camera.fps,
            color_space=s.camera.color_space,
            encoding=s.station.encoding,
            jpeg_quality=s.station.jpeg_quality,
            orb=s.orb,
        )

    def configure(self, orb: dict | None, camera: dict | None, fps: float | None, color_space: str | None) -> Config:
        """The operator's 'Configure': validate, store, and push to every connected phone."""
        data = self.settings.model_dump()
        if orb:
            data["orb"].update(orb)
        if fps is not None:
            data["camera"]["fps"] = fps
        if color_space is not None:
            data["camera"]["color_space"] = color_space
        settings = Settings.model_validate(data)  # raises ValidationError before anything changes
        new_camera = Config.model_validate({"camera": camera}).camera if camera else self.camera  # the wire's checks
        self.settings, self.camera = settings, new_camera
        config = self.config_for_mobile()
        self.store.insert("settings", session_id=None, t=time.time(), source="operator", data_json=config.model_dump_json())
        for session in self.sessions.values():
            session.reply(config)
        self.on_event(None, self.store.log_event(None, "info", "configure", f"settings stored and sent to {len(self.sessions)} mobile station(s)"))
        self.broadcast({"type": "config", "config": config.model_dump()})
        return config

    # --- StationHooks -------------------------------------------------------------------------

    def estimator_settings(self, session: LiveSession) -> tuple[str, str]:
        """The settings a session's new estimator runs with, and why they are lighter than the
        operator's when they are: past ``full_estimator_slots`` sessions (one per core by
        default) a session gets the light VO, so every session keeps a usable pose rate instead
        of all of them collapsing together (issue 34: 0.9 poses/s each for eight SLAM clients)."""
        slots = self.full_estimator_slots()
        if self.settings.estimator not in ("auto", "slam") or session.id in self._full or len(self._full) < slots:
            self._full.add(session.id)
            return self.settings.model_dump_json(), ""
        light = self.settings.model_copy(update={"estimator": "klt-vo"})
        return light.model_dump_json(), f"station at capacity ({slots} sessions with the full estimator): this session runs the light VO (klt-vo)"

    def storage_problem(self) -> str | None:
        return self.storage.problem()

    def check_storage(self) -> None:
        """Tell the operators (and the event log, once it can write) when recording stops or
        works again; the mobile stations hear of it in their status and their frames' errors."""
        problem = self.storage_problem()
        if bool(problem) == self._storage_failing:
            return
        self._storage_failing = bool(problem)
        if problem:
            self.on_event(None, self.store.log_event(None, "error", "storage_full", f"{problem}; new recording refused"))
        else:
            self.on_event(None, self.store.log_event(None, "info", "storage_ok", "recording works again"))
        self.broadcast({"type": "storage", "problem": problem})
        for session in self.sessions.values():
            if session.connected:
                session.reply(session.status())

    def on_pose(self, session: LiveSession, pose: Pose, latency_ms: float) -> None:
        self.broadcast({"type": "pose", "session_id": session.id, "pose": pose.model_dump(), "latency_ms": latency_ms})
        output = self.mavlink.output(session.id, session.device) if self.mavlink is not None else None
        if output is not None:  # each vehicle's own flight controller (mavlink_routes)
            output.update(pose, self._generations.get(session.id, 0) + pose.reset_counter)

    def _mavlink_problem(self, session_id: str, text: str) -> None:
        session = self.sessions.get(session_id)
        if session is not None:
            session.event("warning", "mavlink_down", text)

    def on_gps(self, session: LiveSession, fix: GpsTelemetry) -> None:
        self.broadcast(
            {"type": "gps", "session_id": session.id, "fix": {"timestamp": fix.timestamp, "latitude_deg": fix.latitude_deg, "longitude_deg": fix.longitude_deg}}
        )

    def marker_mission(self, session: LiveSession) -> MarkerMission | None:
        """The marker autopilot for a vehicle in ``autopilot.vehicles`` (on its first camera), its
        set-points on that vehicle's MAVLink route; None for every other session."""
        if session.device not in self.settings.autopilot.vehicles:
            return None
        from evp.station.marker_mission import MarkerMission

        routes = self.mavlink
        connect = (lambda: routes.output(session.id, session.device)) if routes is not None else (lambda: None)
        mission = MarkerMission(session.camera, self.settings, session.event, connect)
        endpoint = "its MAVLink route" if routes is not None else "no MAVLink endpoint (give --mavlink or mavlink.vehicles): nothing is sent"
        session.event("info", "marker_mission", f"{session.device} flies the marker mission (autopilot.vehicles); set-points to {endpoint}")
        return mission

    async def _watchdog_loop(self) -> None:
        """The marker missions' watchdog: a hold when a vehicle's frames stop (evp.station.marker_mission)."""
        while True:
            await asyncio.sleep(self.settings.autopilot.watchdog_period_s)
            for session in list(self.sessions.values()):
                if session.mission is None:
                    continue
                try:
                    session.mission.tick()
                except Exception:  # a bug: logged, the other vehicles' watchdogs go on
                    log.exception("session %s: marker mission watchdog failed", session.id)

    def on_navigation(self, session: LiveSession, state: dict) -> None:
        self.broadcast({"type": "navigation", "session_id": session.id, "navigation": state})

    def on_event(self, session: LiveSession | None, event: dict) -> None:
        self.broadcast({"type": "event", "event": event})
        if session is not None and self.mavlink is not None:
            self.mavlink.alarm(session.id, session.device or session.id, event["code"], event["text"])

    def on_status(self, session: LiveSession) -> None:
        self.broadcast(
            {
                "type": "status",
                "session_id": session.id,
                "status": session.status().model_dump(),
                "connected": session.connected,
                "mission": session.mission is not None,
            }
        )

    def on_new_map(self, session: LiveSession) -> None:
        """A new estimator for a session: its poses start a new frame (MAVLink reset_counter)."""
        self._generations[session.id] = self._generations.get(session.id, 0) + 1

    # --- operators ----------------------------------------------------------------------------

    def broadcast(self, message: dict) -> None:
        text = json.dumps(message)
        for outbox in self.operators:
            if outbox.qsize() < 1000:  # an operator page that stopped reading is not buffered forever
                outbox.put_nowait(text)

    def snapshot(self) -> dict:
        return {
            "type": "snapshot",
            "config": self.config_for_mobile().model_dump(),
            "link": self.link,
            "data_dir": str(self.data_dir.resolve()),
            "db": self.store.engine.url.render_as_string(hide_password=True),
            "mavlink": self.mavlink_url,
            "storage": self.storage_problem(),
            "live": {
                sid: {"status": s.status().model_dump(), "connected": s.connected, "device": s.device, "mission": s.mission is not None}
                for sid, s in self.sessions.items()
            },
            "background": {"url": "/api/background", "bounds_deg": list(bounds)} if (bounds := self.settings.station.background_bounds_deg) else None,
        }

    async def _status_loop(self) -> None:
        loop = asyncio.get_running_loop()
        while True:
            expected = loop.time() + 1.0
            await asyncio.sleep(1.0)
            self.check_storage()
            self._govern(loop.time() - expected)
            for session in list(self.sessions.values()):
                if session.connected:
                    session.reply(session.status())
                    self.store.update_session(session.id, **session.count_columns())
                elif time.monotonic() - session.disconnected_at > self.settings.station.resume_window_s:
                    window = self.settings.station.resume_window_s
                    await self._release(session, f"not resumed within {window:g} s: estimator stopped, recording closed")
                    continue
                self.on_status(session)

    async def _drive_loop(self) -> None:
        """Wheel robots being driven get their command again every ``robot.command_interval_s``."""
        while True:
            await asyncio.sleep(self.settings.robot.command_interval_s)
            now = time.time()  # the clock the session's messages are recorded on
            for session in list(self.sessions.values()):
                if session.connected:
                    session.repeat_drive(now)

    def _govern(self, lag_s: float) -> None:
        """The overload governor's tick (evp.station.overload): one frame rate for every session
        that streams at its own pace (answers at once: phones); a session answered after vision
        keeps a bounded number of frames in flight, so it cannot outrun the station."""
        paced = {s.id: s for s in self.sessions.values() if s.answers == "at_once"}
        for session in self.sessions.values():
            if session.id not in paced:
                session.max_fps = None
        counted, self._frames_counted = self._frames_counted, {i: s.counters.frames_received for i, s in paced.items()}
        rates = [n - counted[i] for i, n in self._frames_counted.items() if i in counted and n > counted[i] and paced[i].connected]
        cap = self.governor.tick(time.monotonic(), lag_s, rates, self.settings.camera.fps)
        if cap is False:
            return
        config = self.config_for_mobile()
        for session in paced.values():
            session.max_fps = cap
            session.reply(config if cap is None else config.model_copy(update={"fps": cap}))
        if cap is None:
            text = f"load back to normal: mobile stations may stream at {config.fps:g} fps again"
        else:
            text = f"CPU overload (the station ran {lag_s * 1000:.0f} ms late): every mobile station capped at {cap:g} fps, frames above it dropped"
        self.on_event(None, self.store.log_event(None, "warning" if cap else "info", "overload", text))

    async def _release(self, session: LiveSession, why: str) -> None:
        """An interrupted session nobody resumed: free its estimator process, close its recording.
        A later resume reopens it from disk with a new map."""
        self.sessions.pop(session.id, None)
        self._full.discard(session.id)
        await session.close("interrupted")
        if self.mavlink is not None:
            self.mavlink.release(session.id)
        session.event("info", "released", why)
        self.broadcast({"type": "sessions"})
