"""The autopilot of seed 003 (Figure 5): lift-off, exploration, navigation, edge detection with
counter-steering, landing; one step per camera frame.

Each step takes the frame's marker observations (None when no frame came) and the range finder's
reading (NaN when it dropped out) and returns a :class:`Command`: a horizontal velocity set-point in
the map frame (for a flight controller that holds velocity, as over MAVLink), the tilt that the
autopilot's own velocity loop asks for (for an attitude-controlled vehicle, as seed 003's
microcontroller), and a climb rate. The velocity loop runs on the camera's motion over the markers
between frames: that is the drift correction of section 3.2.5, with the paper's trims as its
integral. Everything the autopilot decides on bad input is logged in ``events`` (the map logs its
own): frames stopping (hold, then land), the range finder dropping out (height from the markers),
an operator command to a marker not in the map (rejected).
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass, field

import numpy as np

from evp.autopilot.edge_vote import counter_steer
from evp.autopilot.exploration import close_passed, frontier, nearest
from evp.config import AutopilotSettings, MarkerSettings
from evp.markers.detection import MarkerObservation
from evp.markers.marker_map import Localisation, MapEvent, MarkerMap
from evp.markers.planar import camera_over_marker

GRAVITY_M_S2 = 9.80665
# the trims take up a steady drift: they learn only in steady flight (not while a manoeuvre or a
# manual push leaves the velocity far from its set-point, which would wind them up the wrong way)
TRIM_MAX_ERROR_M_S = 0.15
# A single mapped marker in view is checked against where the camera's motion puts it (a second
# marker with its id would teleport the vehicle): only this long after the last fix, as a blind
# stretch (the map's edge) leaves too little of a prediction to judge a marker by (0.6 m/s for
# 0.5 s with a 20 % velocity error is 6 cm, well inside markers.lone_marker_tolerance_m).
PREDICTION_HORIZON_S = 0.5


class State(enum.StrEnum):
    GROUND = "ground"
    LIFT_OFF = "lift_off"
    EXPLORATION = "exploration"
    NAVIGATION = "navigation"
    EDGE = "edge"
    LAND = "land"
    LANDED = "landed"


@dataclass(frozen=True)
class Command:
    time_s: float
    state: State
    velocity_map: np.ndarray  # (2,) m/s set-point, map frame
    tilt_body: np.ndarray  # (2,) rad: forward (nose down), left
    climb_m_s: float
    motors: bool
    holding: bool = False  # frames stopped: level, no push


@dataclass(frozen=True)
class OperatorCommand:
    """What the monitoring station can ask (seed 003's keyboard): goto, land, hold, explore,
    abort, manual (a velocity in the map frame for ``duration_s``; it wins over the autopilot)."""

    kind: str
    marker_id: int | None = None
    velocity: tuple[float, float] = (0.0, 0.0)
    duration_s: float = 1.0


KINDS = ("goto", "land", "hold", "explore", "abort", "manual")


def _limit(vector: np.ndarray, largest: float) -> np.ndarray:
    norm = float(np.linalg.norm(vector))
    return vector if norm <= largest else vector * (largest / norm)


@dataclass
class Autopilot:
    settings: AutopilotSettings
    marker_settings: MarkerSettings
    landing_target: int | None = None
    marker_map: MarkerMap | None = None
    state: State = State.GROUND
    events: list[MapEvent] = field(default_factory=list)
    position: np.ndarray | None = None  # camera (x, y, yaw) in the map frame
    velocity: np.ndarray = field(default_factory=lambda: np.zeros(2))
    height_m: float = float("nan")
    _target: np.ndarray | None = None
    _target_key: tuple | None = None
    _target_since: float = 0.0
    _goal: int | None = None  # marker to navigate to (operator or landing target)
    _hold_point: np.ndarray | None = None
    _hover_until: float | None = None
    _closed: set = field(default_factory=set)
    _frontier: dict = field(default_factory=dict)
    _frontier_size: tuple = ()
    _trim: np.ndarray = field(default_factory=lambda: np.zeros(2))
    _tilt_map: np.ndarray = field(default_factory=lambda: np.zeros(2))
    _last_frame_s: float | None = None
    _last_step_s: float | None = None
    _last_marker_s: float | None = None
    _last_fix_s: float | None = None
    _last_new_marker_s: float = 0.0
    _last_range_s: float | None = None
    _last_markers: dict = field(default_factory=dict)
    _last_marker_xy: np.ndarray | None = None
    _counter: np.ndarray | None = None
    _manual: tuple | None = None
    _before_edge: State = State.EXPLORATION
    _time: float = 0.0
    _holding_logged: bool = False
    _range_logged: bool = False

    def __post_init__(self) -> None:
        if self.marker_map is None:
            self.marker_map = MarkerMap(self.marker_settings, min_frames=self.settings.min_marker_frames)
        self._goal = self.landing_target

    @property
    def time_s(self) -> float:
        """The time of the last frame, watchdog step or command."""
        return self._time

    def log(self, kind: str, detail: str) -> None:
        self.events.append(MapEvent(self._time, kind, detail))

    def _set_state(self, state: State, why: str) -> None:
        if state != self.state:
            self.log("state", f"{self.state.value} -> {state.value}: {why}")
            self.state = state

    # --- operator ------------------------------------------------------------------------------
    def command(self, time_s: float, order: OperatorCommand) -> bool:
        """Apply an operator command; False (and logged) when it is refused."""
        self._time = time_s
        if order.kind not in KINDS:
            self.log("command_rejected", f"unknown command {order.kind!r}")
            return False
        if order.kind == "manual":
            self._manual = (np.array(order.velocity, float), time_s + order.duration_s)
            self.log("command", f"manual velocity {order.velocity} for {order.duration_s} s")
            return True
        if self.state in (State.GROUND, State.LANDED) and order.kind != "goto":
            self.log("command_rejected", f"{order.kind}: the vehicle is not flying")
            return False
        if order.kind in ("goto", "land") and order.marker_id is not None and order.marker_id not in self.marker_map.poses:
            self.log("command_rejected", f"{order.kind} {order.marker_id}: marker not in the map")
            return False
        self.log("command", f"{order.kind}" + (f" {order.marker_id}" if order.marker_id is not None else ""))
        if order.kind == "goto":
            self._goal, self.landing_target = order.marker_id, None
        elif order.kind == "land":
            self.landing_target = order.marker_id
            self._goal = order.marker_id
            if order.marker_id is None:
                self._set_state(State.LAND, "operator: land here")
        elif order.kind == "hold":
            self._goal = None
            self._hold_point = None if self.position is None else self.position[:2].copy()
            self._hover_until = math.inf
        elif order.kind == "explore":
            self._goal, self._hover_until, self._hold_point = None, None, None
            if self.state == State.NAVIGATION:
                self._set_state(State.EXPLORATION, "operator: explore")
        elif order.kind == "abort":
            self._goal, self.landing_target = None, None
            self._set_state(State.LAND, "operator: abort")
        return True

    def hover(self, seconds: float) -> None:
        """Hold over the lift-off place for this long after lift-off, then land (the drift test)."""
        self._hover_until = seconds

    # --- one frame -----------------------------------------------------------------------------
    def step(self, time_s: float, observations: list[MarkerObservation] | None, range_m: float) -> Command:
        dt = 0.0 if self._last_step_s is None else max(0.0, time_s - self._last_step_s)
        self._time = self._last_step_s = time_s
        localisation = None
        if observations is not None:
            self._last_frame_s = time_s
            self._holding_logged = False
            size = len(self.marker_map)
            localisation = self.marker_map.update(time_s, observations, self._predicted_xy(time_s, dt))
            if len(self.marker_map) > size:
                self._last_new_marker_s = time_s
            self._track(time_s, observations, localisation, dt)
        self._update_height(time_s, range_m, localisation)
        if self.state == State.GROUND:
            self._set_state(State.LIFT_OFF, "start")
        if self.state == State.LANDED:
            return Command(time_s, self.state, np.zeros(2), np.zeros(2), 0.0, False)
        frames_missing = self._last_frame_s is None or time_s - self._last_frame_s > self.settings.frame_timeout_s
        if frames_missing and self._last_frame_s is not None:
            return self._without_frames(time_s)
        self._transitions(time_s, localisation)
        velocity = self._velocity_setpoint(time_s)
        return Command(time_s, self.state, velocity, self._tilt(velocity, dt, localisation is not None), self._climb(), True)

    def _track(self, time_s: float, observations: list[MarkerObservation], localisation: Localisation | None, dt: float) -> None:
        """Position from the map (carried forward by the velocity while no mapped marker is seen);
        velocity from the markers seen in this frame and the last, mapped or not (section 3.2.5),
        else carried by the tilt commanded and the drag."""
        if localisation is not None:
            self.position = localisation.pose
            self._last_fix_s = time_s
        moved = self._marker_motion(observations, localisation, dt)
        if moved is not None:
            alpha = min(1.0, dt / self.settings.velocity_smoothing_s)
            self.velocity = (1 - alpha) * self.velocity + alpha * moved
        elif not observations and self.state not in (State.GROUND, State.LANDED):
            acceleration = GRAVITY_M_S2 * np.tan(self._tilt_map) - self.settings.drag_per_s * self.velocity
            self.velocity = self.velocity + acceleration * dt
        if localisation is None and self.position is not None and self.state not in (State.GROUND, State.LANDED):
            self.position = self.position + np.array([*(self.velocity * dt), 0.0])
        if observations:
            self._last_marker_s = time_s
        if localisation is None:
            return
        nearest_id = min(localisation.marker_ids, key=lambda i: np.linalg.norm(self.marker_map.poses[i][:2] - self.position[:2]))
        self._last_marker_xy = self.marker_map.poses[nearest_id][:2].copy()
        if self.state == State.LIFT_OFF or not self._in_band() or self.height_m < 0.8 * self.settings.flight_level_m:
            return  # below the flight level the view is too small to tell an empty place
        places = self._open_places()
        for key in close_passed(places, self.position[:2], self.settings.close_radius_m):
            self._closed.add(key)
            self._frontier_size = ()

    def _predicted_xy(self, time_s: float, dt: float) -> np.ndarray | None:
        """Where the camera's motion puts it at this frame, while the last fix is fresh."""
        if self.position is None or self._last_fix_s is None or time_s - self._last_fix_s > PREDICTION_HORIZON_S:
            return None
        return self.position[:2] + self.velocity * dt

    def _marker_motion(self, observations: list[MarkerObservation], localisation: Localisation | None, dt: float) -> np.ndarray | None:
        """Camera velocity (map frame) from the markers seen in both this frame and the last: with
        the map's joint camera pose when it has one; else from each marker's own pose, the camera's
        step over the marker turned into the map by Eq. 1's yaw (the median over the markers, as a
        single small square's pose can flip by centimetres between frames)."""
        previous, self._last_markers = self._last_markers, {}
        if not observations:
            return None
        if localisation is not None:
            now = dict(localisation.camera_by_marker)
        else:
            yaw = np.pi / 2 if self.position is None else self.position[2]
            now = {}
            for o in observations:
                x, y, phi = camera_over_marker(o)
                turn = yaw - phi - np.pi / 2  # the marker's heading in the map
                c, s_ = np.cos(turn), np.sin(turn)
                now[o.marker_id] = np.array([c * x - s_ * y, s_ * x + c * y])
        self._last_markers = {("map" if localisation is not None else "own", i): xy for i, xy in now.items()}
        common = [key for key in self._last_markers if key in previous]
        if not common or dt <= 0:
            return None
        return np.median([self._last_markers[key] - previous[key] for key in common], axis=0) / dt

    def _open_places(self) -> dict:
        size = (len(self.marker_map), len(self._closed), self.marker_map.pitch_m)
        if size != self._frontier_size:
            self._frontier = frontier(self.marker_map, self._closed)
            self._frontier_size = size
        return self._frontier

    def _update_height(self, time_s: float, range_m: float, localisation: Localisation | None) -> None:
        if np.isfinite(range_m):
            self.height_m = float(range_m)
            self._last_range_s = time_s
            self._range_logged = False
            return
        if self._last_range_s is not None and time_s - self._last_range_s <= self.settings.range_timeout_s:
            return  # a short gap: the last reading stands
        if not self._range_logged:
            self.log("range_dropout", "no range reading: height from the markers" if localisation else "no range reading and no marker: height held")
            self._range_logged = True
        if localisation is not None:
            self.height_m = localisation.height_m

    def _in_band(self) -> bool:
        return self.settings.band_low_m <= self.height_m <= self.settings.band_high_m

    def _transitions(self, time_s: float, localisation: Localisation | None) -> None:
        s = self.settings
        if self.state == State.LIFT_OFF:
            if np.isfinite(self.height_m) and self.height_m >= s.flight_level_m - 0.05:
                self._hold_point = None if self.position is None else self.position[:2].copy()
                if self._hover_until is not None:
                    self._hover_until = time_s + self._hover_until
                self._set_state(State.EXPLORATION, "flight level reached")
            return
        if self.state == State.LAND:
            if np.isfinite(self.height_m) and self.height_m <= s.touchdown_m:
                self._set_state(State.LANDED, "touchdown")
            return
        lost = self._last_marker_s is None or time_s - self._last_marker_s > s.edge_timeout_s
        if self.state == State.EDGE:
            if not lost:
                self._set_state(self._before_edge, "markers tracked again")
                self._counter = None
            elif time_s - self._last_marker_s > s.edge_land_after_s:
                self.log("edge_lost", f"no marker for {s.edge_land_after_s} s after the edge: landing where it is")
                self._counter, self._goal, self.landing_target = None, None, None
                self._set_state(State.LAND, "map not found again")
            return
        if lost and self._in_band() and self._last_marker_xy is not None:
            self._enter_edge(time_s)
            return
        if self._hover_until is not None:
            if time_s >= self._hover_until:
                self._set_state(State.LAND, "hover time over")
            return
        if self._goal is not None and self._goal in self.marker_map.poses:
            goal_xy = self.marker_map.poses[self._goal][:2]
            self._target, self._target_key = goal_xy, ("marker", self._goal)
            self._set_state(State.NAVIGATION, f"to marker {self._goal}")
            if self.landing_target == self._goal and self._over(goal_xy, s.land_radius_m, s.land_max_speed_m_s):
                self._set_state(State.LAND, f"over marker {self._goal}")
            return
        self._explore(time_s)

    def _over(self, xy: np.ndarray, radius: float, speed: float) -> bool:
        return self.position is not None and np.linalg.norm(self.position[:2] - xy) <= radius and np.linalg.norm(self.velocity) <= speed

    def _explore(self, time_s: float) -> None:
        s = self.settings
        places = self._open_places()
        if self.state == State.NAVIGATION and self._target_key is not None and self._target_key[0] != "marker":
            reached = self._target_key not in places
            if time_s - self._target_since > s.target_timeout_s and not reached:
                self._closed.add(self._target_key)
                self._frontier_size = ()
                self.log("target_given_up", f"{self._target_key} not reached in {s.target_timeout_s} s")
                reached = True
            if not reached:
                return
            self._set_state(State.EXPLORATION, "target reached")
            self._target, self._target_key = None, None
        if self.state == State.NAVIGATION:  # a goal that is gone (or none): explore again
            self._set_state(State.EXPLORATION, "no goal")
        if time_s - self._last_new_marker_s < s.explore_interval_s or self.position is None:
            return
        if not np.isfinite(self.marker_map.pitch_m):
            return  # one marker so far: no neighbour direction to explore yet (hold and look)
        choice = nearest(self._open_places(), self.position[:2])
        if choice is not None:  # near enough to see the place is enough: stop short of it, over the map
            key, place = choice
            marker_xy = self.marker_map.poses[key[0]][:2]
            offset = place - marker_xy
            choice = (key, marker_xy + offset * max(0.0, 1.0 - 0.8 * s.close_radius_m / max(np.linalg.norm(offset), 1e-9)))
        if choice is None:
            if self._target_key != ("done",):
                self.log("explored", f"no unexplored place left; {len(self.marker_map)} markers mapped")
                if self.landing_target is not None:
                    self.log("target_unknown", f"landing marker {self.landing_target} not found in the map: landing at the start")
                self._target_key = ("done",)
                self.landing_target = self.marker_map.root
                self._goal = self.marker_map.root
            return
        self._target_key, self._target = choice
        self._target_since = time_s
        self._set_state(State.NAVIGATION, f"unexplored place {choice[0]}")

    def _enter_edge(self, time_s: float) -> None:
        poses = np.array([p[:2] for p in self.marker_map.poses.values()])
        lo, hi = poses.min(axis=0), poses.max(axis=0)
        since = time_s - self._last_marker_s
        exit_xy = self.position[:2]  # carried forward since the last marker
        vote = counter_steer(
            exit_xy,
            self._last_marker_xy,
            (lo + hi) / 2,
            (hi - lo) / 2 + self.marker_map.pitch_m / 2,
            len(self.marker_map),
            self.velocity,
            self.marker_map.pitch_m,
            tuple(self.settings.vote_weights),
        )
        self._counter = vote.counter_steer
        self._before_edge = self.state
        self.log(
            "edge",
            f"no marker for {since * 1000:.0f} ms: counter-steer ({vote.counter_steer[0]:+.2f}, {vote.counter_steer[1]:+.2f}), votes E/W/N/S {np.round(vote.votes, 2).tolist()}",
        )
        self._set_state(State.EDGE, "map edge")

    def _velocity_setpoint(self, time_s: float) -> np.ndarray:
        s = self.settings
        if self._manual is not None:
            if time_s < self._manual[1]:
                return _limit(self._manual[0], s.max_speed_m_s)
            self._manual = None
            self.log("manual_end", "manual velocity over: autopilot resumes")
        if self.state == State.EDGE and self._counter is not None:
            return self._counter * s.max_speed_m_s
        if self.position is None or self.state == State.LIFT_OFF:
            return np.zeros(2)
        if self.state == State.LAND and self.landing_target is not None and self.landing_target in self.marker_map.poses:
            target = self.marker_map.poses[self.landing_target][:2]
        elif self.state == State.NAVIGATION and self._target is not None:
            target = self._target
        else:
            if not s.drift_correction:
                return np.zeros(2)  # uncorrected: nothing holds the place, as in seed 003's drift test
            if self._hold_point is None:
                self._hold_point = self.position[:2].copy()
            target = self._hold_point
        if self.state == State.NAVIGATION:
            self._hold_point = None
        return _limit(s.position_gain * (target - self.position[:2]), s.max_speed_m_s)

    def _tilt(self, velocity: np.ndarray, dt: float, tracked: bool) -> np.ndarray:
        """Tilt (body frame) from the velocity error; the trims integrate it while markers track."""
        s = self.settings
        if self.state == State.EDGE and self._counter is not None and self._manual is None:
            outward = min(0.0, float(self.velocity @ self._counter))  # brake what is left of the exit velocity
            along = self._counter * (s.counter_steer_tilt_rad - s.velocity_gain * outward) + (self._trim if s.drift_correction else 0.0)
        elif not s.drift_correction:
            along = velocity * s.velocity_gain
        else:
            error = velocity - self.velocity
            if tracked and self._manual is None and self.state != State.LIFT_OFF and np.linalg.norm(error) < TRIM_MAX_ERROR_M_S:
                self._trim = _limit(self._trim + s.trim_gain * error * dt, s.max_trim_rad)
            along = s.velocity_gain * error + self._trim
        tilt_map = _limit(along, s.max_tilt_rad)
        self._tilt_map = tilt_map
        yaw = 0.0 if self.position is None else self.position[2]
        c, s_ = math.cos(yaw), math.sin(yaw)
        return np.array([c * tilt_map[0] + s_ * tilt_map[1], -s_ * tilt_map[0] + c * tilt_map[1]])

    def _climb(self) -> float:
        s = self.settings
        if not np.isfinite(self.height_m):
            return s.climb_rate_m_s * 0.5 if self.state == State.LIFT_OFF else 0.0
        if self.state == State.LAND:
            return -s.land_rate_m_s
        if self.state == State.LIFT_OFF:
            return s.climb_rate_m_s
        return float(np.clip(s.altitude_gain * (s.flight_level_m - self.height_m), -s.climb_rate_m_s, s.climb_rate_m_s))

    def _without_frames(self, time_s: float) -> Command:
        """Frames stopped: hold level at height; after ``land_after_s`` land where it is."""
        s = self.settings
        missing = time_s - self._last_frame_s
        if missing > s.land_after_s and self.state not in (State.LAND, State.LANDED):
            self.log("frames_stopped", f"no frame for {missing:.1f} s: landing")
            self._set_state(State.LAND, "no frames")
        elif not self._holding_logged:
            self.log("frames_stopped", f"no frame for {missing:.2f} s: holding")
            self._holding_logged = True
        if self.state == State.LAND and np.isfinite(self.height_m) and self.height_m <= s.touchdown_m:
            self._set_state(State.LANDED, "touchdown")
        yaw = 0.0 if self.position is None else self.position[2]
        c, s_ = math.cos(yaw), math.sin(yaw)
        trim = self._trim if s.drift_correction else np.zeros(2)
        tilt = np.array([c * trim[0] + s_ * trim[1], -s_ * trim[0] + c * trim[1]])
        return Command(time_s, self.state, np.zeros(2), tilt, self._climb(), self.state != State.LANDED, holding=True)
