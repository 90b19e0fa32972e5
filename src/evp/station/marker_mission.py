"""A station session that flies seed 003's marker mission: the phone's frames and range finder
drive the autopilot, and its velocity set-points go to that vehicle's flight controller.

A session is a marker mission when its mobile station's device name (``hello.device``) is in
``autopilot.vehicles``: the station's settings, not the phone, decide which vehicle the station
may fly. Each frame, once recorded, is decoded, its markers detected and the autopilot stepped,
in the station's event loop (a few ms per 640x480 frame: ``bench/marker_autopilot.py``), whether
or not the pose estimator runs. The range finder comes as ``range`` telemetry; each reading is
used once, with the next frame, so a range finder that stops is a dropout the autopilot sees
(``range_timeout_s``). The command goes out through :class:`MavlinkAutopilotLink` on the vehicle's
own MAVLink connection, the one its ODOMETRY uses (``evp.station.mavlink_routes``): set-points
only while the controller is armed in GUIDED/OFFBOARD, so the pilot's mode switch always wins.
``tick`` is the watchdog the station calls every ``autopilot.watchdog_period_s``: frames that
stop hold position, then land. The operator's commands (:func:`parse_command`) reach the
autopilot between two frames. Everything the autopilot and its map log becomes a session event
(the operator's log and the database), bad input at warning level.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable

from evp.autopilot.pilot import KINDS, Autopilot, Command, OperatorCommand
from evp.config import Settings
from evp.errors import FrameError
from evp.markers.detection import MarkerDetector
from evp.station.mavlink_autopilot import MavlinkAutopilotLink
from evp.station.protocol import ImageMessage, ProtocolError, image_pixels
from evp.types import CameraModel

EVENTS_SHOWN = 12
# A bad input that persists (a duplicated marker in view, a range finder that stays silent) is
# logged by the map on every frame: the session's log gets each kind at most once per this many
# seconds, with the count held back, as the navigation stage's notices (evp.station.estimation).
REPEAT_S = 5.0
ALWAYS_TOLD = frozenset({"state", "command", "command_rejected", "manual_override", "in_control", "mavlink"})
# What the autopilot and its map log on bad input or when they give something up: warnings for
# the operator. Everything else (state changes, markers mapped, commands) is information.
WARNING_KINDS = frozenset(
    {
        "command_rejected",
        "frames_stopped",
        "range_dropout",
        "duplicate_id",
        "inconsistent_markers",
        "unconfirmed_marker",
        "manual_override",
        "no_setpoint",
        "edge",
        "edge_lost",
        "target_unknown",
        "target_given_up",
        "bad_frame",
        "mavlink_down",
    }
)


def parse_command(body) -> OperatorCommand:
    """An operator command from its JSON (``{kind, marker_id?, velocity?, duration_s?}``); a
    ValueError says what is wrong. Whether the autopilot takes it is the autopilot's decision."""
    try:
        kind = str(body["kind"])
        marker = None if body.get("marker_id") in (None, "") else int(body["marker_id"])
        velocity = tuple(float(v) for v in body.get("velocity", (0.0, 0.0)))
        duration = float(body.get("duration_s", 1.0))
    except (ValueError, KeyError, TypeError, AttributeError) as exc:
        raise ValueError(f"bad command: {exc}; want {{kind: {'|'.join(KINDS)}, marker_id?, velocity?, duration_s?}}") from None
    if len(velocity) < 2 or not all(math.isfinite(v) for v in (*velocity, duration)):
        raise ValueError("bad command: velocity is two finite numbers (m/s, map frame) and duration_s a finite number")
    return OperatorCommand(kind, marker, velocity[:2], duration)


def pilot_view(pilot: Autopilot, t: float, done: bool, markers_total: int | None) -> dict:
    """What the mission page shows: time, state, height, the camera on the map, the map and its grid."""
    marker_map = pilot.marker_map
    grid = marker_map.grid()
    events = sorted(pilot.events + marker_map.events, key=lambda e: e.time_s)[-EVENTS_SHOWN:]
    return {
        "t": t,
        "state": pilot.state.value,
        "done": done,
        "height_m": pilot.height_m if math.isfinite(pilot.height_m) else None,
        "band_m": [pilot.settings.band_low_m, pilot.settings.band_high_m],
        "position": None if pilot.position is None else [float(v) for v in pilot.position],
        "target": pilot.landing_target,
        "markers": [{"id": i, "x": float(p[0]), "y": float(p[1]), "grid": list(grid[i]) if i in grid else None} for i, p in sorted(marker_map.poses.items())],
        "markers_total": markers_total,
        "events": [{"t": round(e.time_s, 2), "kind": e.kind, "detail": e.detail} for e in events],
    }


class MarkerMission:
    """One vehicle's marker mission. ``report(level, code, text)`` logs a session event;
    ``connect()`` gives the vehicle's MAVLink output (None while it has none: asked again at
    each tick)."""

    def __init__(
        self, camera: CameraModel, settings: Settings, report: Callable[[str, str, str], None], connect: Callable[[], object | None], clock=time.monotonic
    ):
        self.settings = settings
        self.report = report
        self._connect = connect
        self.detector = MarkerDetector(camera, settings.markers)
        self.pilot = Autopilot(settings.autopilot, settings.markers)
        self.link = MavlinkAutopilotLink(None, self.pilot, clock)
        self.last_command: Command | None = None
        self._range = math.nan
        self._told = (0, 0)  # pilot events, map events reported so far
        self._bad_frame_told = False
        self._link_failing = False
        self._told_at: dict[str, float] = {}
        self._held: dict[str, int] = {}
        self._attach()

    def set_camera(self, camera: CameraModel) -> None:
        """A new calibration from the phone: same map and state, new detector."""
        self.detector = MarkerDetector(camera, self.settings.markers)

    def on_range(self, distance_m: float) -> None:
        self._range = distance_m

    def on_frame(self, message: ImageMessage) -> Command | None:
        """Detect, step, send. A frame that does not decode is no frame for the autopilot (the
        watchdog holds when they keep failing), told once until one decodes again."""
        try:
            observations = self.detector.detect(image_pixels(message))
        except (ProtocolError, FrameError) as exc:
            if not self._bad_frame_told:
                self.pilot.log("bad_frame", f"frame {message.seq} not used by the autopilot: {exc}")
                self._bad_frame_told = True
            self._tell()
            return None
        self._bad_frame_told = False
        reading, self._range = self._range, math.nan
        self.last_command = self._guarded(lambda: self.link.on_frame(message.timestamp, observations, reading))
        return self.last_command

    def tick(self) -> None:
        """The watchdog: the vehicle's link (once it has one), heartbeats, a hold when frames stopped."""
        self._attach()
        command = self._guarded(self.link.tick)
        if command is not None:
            self.last_command = command

    def command(self, order: OperatorCommand) -> tuple[bool, str]:
        """(accepted, the autopilot's reason)."""
        accepted = self.pilot.command(self.pilot.time_s, order)
        detail = self.pilot.events[-1].detail if self.pilot.events else ""
        self._tell()
        return accepted, detail

    def view(self) -> dict:
        return pilot_view(self.pilot, self.pilot.time_s, False, None)

    def _attach(self) -> None:
        if self.link.connection is not None:
            return
        output = self._connect()
        if output is not None:
            self.link.connection, self.link.lock = output.connection, output.send_lock
            self.pilot.log("mavlink", f"velocity set-points to {output.url} once its controller is armed in GUIDED/OFFBOARD")
            self._tell()

    def _guarded(self, step: Callable[[], Command | None]) -> Command | None:
        """One step; an endpoint that refuses (a TCP autopilot gone) is told, and the step's
        decisions stand (logged) whatever the link does."""
        try:
            command = step()
        except OSError as exc:
            if not self._link_failing:
                self.pilot.log("mavlink_down", f"set-point not sent: {exc}")
            self._link_failing = True
            return None
        else:
            self._link_failing = False
            return command
        finally:
            self._tell()

    def _tell(self) -> None:
        """The autopilot's and the map's new events, as session events."""
        pilot_told, map_told = self._told
        events = self.pilot.events[pilot_told:] + self.pilot.marker_map.events[map_told:]
        self._told = (len(self.pilot.events), len(self.pilot.marker_map.events))
        for event in sorted(events, key=lambda e: e.time_s):
            if event.kind not in ALWAYS_TOLD and event.time_s - self._told_at.get(event.kind, -math.inf) < REPEAT_S:
                self._held[event.kind] = self._held.get(event.kind, 0) + 1
                continue
            held = self._held.pop(event.kind, 0)
            self._told_at[event.kind] = event.time_s
            more = f" ({held} more like it before)" if held else ""
            self.report("warning" if event.kind in WARNING_KINDS else "info", f"autopilot_{event.kind}", f"t={event.time_s:.2f} s: {event.detail}{more}")
