"""Closed-loop missions over seed 003's marker floor: the autopilot flies the simulated quadrotor.

Each frame the camera image is rendered from the vehicle's true pose (the existing renderer and the
``marker-field`` scene), the markers are detected, the autopilot steps and its command drives the
vehicle until the next frame. The sonar is the range model's (distance along the body's down axis,
``RangeConfig``'s noise). Scripted faults (frame gaps, range-finder gaps, operator commands) test
the autopilot's handling of bad input. A mission ends landed, at its duration, or out of the room.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace

import cv2
import numpy as np

from evp.autopilot.pilot import Autopilot, Command, OperatorCommand, State
from evp.config import AutopilotSettings, MarkerSettings
from evp.errors import UsageError
from evp.markers.detection import MarkerDetector
from evp.markers.marker_map import MarkerMap
from evp.sim.quadrotor import Quadrotor, QuadrotorConfig
from evp.sim.scenarios import DOWNWARD, SimOptions, build_scenario
from evp.sim.sensors import RangeConfig
from evp.sim.textures import MARKER_COLS, MARKER_ROWS, marker_field_texture
from evp.sim.world import Renderer, ray_distance
from evp.types import CameraModel

ROOM_HALF_M = 2.0  # seed 003: a 4 x 4 m room
VEHICLE_RADIUS_M = 0.29  # seed 003: 580 mm across
IMAGE_NOISE_SIGMA = 2.0  # grey levels of read noise on every frame
PHYSICS_STEPS_PER_FRAME = 6


@dataclass
class MissionSpec:
    seed: int = 1
    target: int | None = None
    start_marker: int = 49  # the middle of the 9 x 11 field
    duration_s: float = 150.0
    hover_s: float | None = None
    fps: float = 30.0
    resolution: tuple[int, int] = (640, 480)
    commands: list[tuple[float, OperatorCommand]] = field(default_factory=list)
    frame_gaps: list[tuple[float, float]] = field(default_factory=list)  # (start, duration) without frames
    range_gaps: list[tuple[float, float]] = field(default_factory=list)
    prior_map: MarkerMap | None = None
    vehicle: QuadrotorConfig = field(default_factory=QuadrotorConfig)
    range: RangeConfig = field(default_factory=RangeConfig)


@dataclass
class MissionResult:
    spec: MissionSpec
    times: np.ndarray
    true_positions: np.ndarray  # (N, 3) body origin
    estimated: np.ndarray  # (N, 3) x, y, yaw in the map frame (NaN before the first marker)
    heights: np.ndarray  # range readings (NaN: dropout)
    states: list[str]
    mapped: np.ndarray  # markers in the map after each frame
    frame_ms: np.ndarray  # autopilot time per frame: detection, map, command
    commands: list[Command]
    autopilot: Autopilot
    marker_centres: dict[int, np.ndarray]  # true world (x, y) of every marker
    map_origin: np.ndarray  # world (x, y, theta) of the map frame (the root marker's true pose)
    left_room: bool

    def summary(self) -> dict:
        """The mission's figures (``mission.json``)."""
        ap = self.autopilot
        landed = ap.state == State.LANDED
        target = self.spec.target
        final = self.true_positions[-1, :2]
        landing_error = float(np.linalg.norm(final - self.marker_centres[target])) if landed and target is not None else None
        flying = np.array([s in (State.EXPLORATION.value, State.NAVIGATION.value, State.EDGE.value) for s in self.states])
        heights = self.true_positions[:, 2]
        low, high = ap.settings.band_low_m, ap.settings.band_high_m
        real_ids = set(self.marker_centres)
        mapped_ids = set(ap.marker_map.poses) & real_ids
        total = len(self.marker_centres)
        reach_95 = np.flatnonzero(self.mapped >= math.ceil(0.95 * total))
        return {
            "landed": bool(landed),
            "landing_error_m": landing_error,
            "markers_mapped": len(mapped_ids),
            "markers_total": total,
            "mission_time_s": float(self.times[-1] - self.times[0]) if len(self.times) else 0.0,
            "left_room": bool(self.left_room),
            "frame_ms_p95": float(np.percentile(self.frame_ms, 95)) if len(self.frame_ms) else None,
            "frame_ms_median": float(np.median(self.frame_ms)) if len(self.frame_ms) else None,
            "time_to_95pct_mapped_s": float(self.times[reach_95[0]]) if len(reach_95) else None,
            "flight_level_in_band_fraction": float(np.mean((heights[flying] >= low) & (heights[flying] <= high))) if flying.any() else None,
            "map_position_error_m": self.map_error(),
            "final_state": ap.state.value,
            "seed": self.spec.seed,
            "target": target,
            "events": len(ap.events) + len(ap.marker_map.events),
        }

    def map_error(self) -> float | None:
        """RMS distance of the mapped markers from their true places (map frame put on the root's true pose)."""
        poses = self.autopilot.marker_map.poses
        errors = [np.linalg.norm(self.to_world(p[:2]) - self.marker_centres[i]) for i, p in poses.items() if i in self.marker_centres]
        return float(np.sqrt(np.mean(np.square(errors)))) if errors else None

    def to_world(self, xy: np.ndarray) -> np.ndarray:
        x, y, theta = self.map_origin
        c, s = math.cos(theta), math.sin(theta)
        return np.array([x + c * xy[0] - s * xy[1], y + s * xy[0] + c * xy[1]])

    def over_map(self) -> np.ndarray:
        """Per frame: the body above the marker field's rectangle."""
        centres = np.array(list(self.marker_centres.values()))
        lo, hi = centres.min(axis=0) - 0.098, centres.max(axis=0) + 0.098
        xy = self.true_positions[:, :2]
        return np.all((xy >= lo) & (xy <= hi), axis=1)


def mission_camera(resolution: tuple[int, int]) -> CameraModel:
    """The phone camera looking down: the Nexus 5X's lens at 4:3 (640 x 480), scaled for smaller images."""
    base = build_scenario("marker-field", SimOptions(duration_s=1.0)).camera
    full = replace(base, height=480, cy=base.cy + 50.0, name="nexus5x_640x480")
    return full if resolution == (640, 480) else full.scaled(*resolution)


def marker_world_centres() -> dict[int, np.ndarray]:
    texture, mpt, centres = marker_field_texture()
    origin = -np.array([texture.shape[1] * mpt, texture.shape[0] * mpt]) / 2
    return {i: origin + c for i, c in centres.items()}


def _in(windows: list[tuple[float, float]], t: float) -> bool:
    return any(start <= t < start + duration for start, duration in windows)


class MissionRun:
    """One mission, a frame at a time (``step``), so a live station can pace it and send the
    operator's commands between frames; ``fly`` runs one to its end."""

    def __init__(
        self,
        spec: MissionSpec,
        autopilot_settings: AutopilotSettings | None = None,
        marker_settings: MarkerSettings | None = None,
        clock: Callable[[], float] = time.thread_time,
    ):
        autopilot_settings = autopilot_settings or AutopilotSettings()
        marker_settings = marker_settings or MarkerSettings()
        for name, marker in (("target", spec.target), ("start", spec.start_marker)):
            if marker is not None and not 0 <= marker < MARKER_COLS * MARKER_ROWS:
                raise UsageError(f"--{name} {marker}: the field's markers are 0-{MARKER_COLS * MARKER_ROWS - 1}")
        self.spec = spec
        self.clock = clock
        self.rng = np.random.default_rng(spec.seed)
        self.centres = marker_world_centres()
        self.scene = build_scenario("marker-field", SimOptions(duration_s=1.0)).scene
        camera = mission_camera(spec.resolution)
        self.renderer = Renderer(camera, self.scene)
        self.detector = MarkerDetector(camera, marker_settings)
        self.vehicle = Quadrotor(spec.vehicle, self.rng, self.centres[spec.start_marker] + self.rng.normal(0, 0.01, 2))
        self.pilot = Autopilot(autopilot_settings, marker_settings, landing_target=spec.target, marker_map=spec.prior_map)
        if spec.hover_s is not None:
            self.pilot.hover(spec.hover_s)
        self.commands = sorted(spec.commands, key=lambda c: c[0])
        self.frame_dt = 1.0 / spec.fps
        self.records: dict[str, list] = {k: [] for k in ("times", "truth", "estimated", "heights", "states", "mapped", "frame_ms", "issued")}
        self._noise = np.empty((camera.height, camera.width), np.float32)
        cv2.setRNGSeed(spec.seed)
        self.left_room = False
        self.done = False
        self.t = 0.0

    def sense(self) -> tuple[np.ndarray | None, float]:
        """The camera's image (None in a scripted frame gap) and the sonar's reading (NaN: out of
        range or a scripted gap) from the vehicle's true pose now."""
        spec, t, s = self.spec, self.t, self.vehicle.state
        R = s.rotation()
        distance = ray_distance(self.scene, s.position, R @ np.array([0.0, 0.0, -1.0]))
        reading = distance + self.rng.normal(0, spec.range.noise_m) if distance <= spec.range.max_range_m and not _in(spec.range_gaps, t) else float("nan")
        if _in(spec.frame_gaps, t):
            return None, reading
        T = np.eye(4)
        T[:3, :3] = R @ DOWNWARD
        T[:3, 3] = s.position
        image = self.renderer.render(T).astype(np.float32)
        cv2.randn(self._noise, 0.0, IMAGE_NOISE_SIGMA)
        return np.clip(image + self._noise, 0, 255).astype(np.uint8), reading

    def step(self) -> bool:
        """One frame: sense, decide, move. False once the mission is over."""
        if self.done or self.t > self.spec.duration_s:
            self.done = True
            return False
        pilot, t, r = self.pilot, self.t, self.records
        while self.commands and self.commands[0][0] <= t:
            pilot.command(t, self.commands.pop(0)[1])
        s = self.vehicle.state
        frame, reading = self.sense()
        if frame is not None:
            began = self.clock()
            command = pilot.step(t, self.detector.detect(frame), reading)
            r["frame_ms"].append((self.clock() - began) * 1000.0)
        else:
            command = pilot.step(t, None, reading)
        r["issued"].append(command)
        r["times"].append(t)
        r["truth"].append(s.position.copy())
        r["estimated"].append(pilot.position.copy() if pilot.position is not None else np.full(3, np.nan))
        r["heights"].append(reading)
        r["states"].append(pilot.state.value)
        r["mapped"].append(len(set(pilot.marker_map.poses) & set(self.centres)))
        if pilot.state == State.LANDED:
            self.done = True
            return False
        for _ in range(PHYSICS_STEPS_PER_FRAME):
            self.vehicle.step(command.tilt_body, command.climb_m_s, command.motors, self.frame_dt / PHYSICS_STEPS_PER_FRAME)
        if np.any(np.abs(self.vehicle.state.position[:2]) > ROOM_HALF_M - VEHICLE_RADIUS_M):
            self.left_room = self.done = True
            pilot.log("left_room", f"the vehicle reached the room's wall at {self.vehicle.state.position[:2].round(2).tolist()}")
            return False
        self.t = round(t + self.frame_dt, 9)
        return True

    def result(self) -> MissionResult:
        r = self.records
        root = self.pilot.marker_map.root
        origin = np.array([*self.centres[root], 0.0]) if root in self.centres else np.zeros(3)
        return MissionResult(
            self.spec,
            np.array(r["times"]),
            np.array(r["truth"]).reshape(-1, 3),
            np.array(r["estimated"]).reshape(-1, 3),
            np.array(r["heights"]),
            r["states"],
            np.array(r["mapped"]),
            np.array(r["frame_ms"]),
            r["issued"],
            self.pilot,
            self.centres,
            origin,
            self.left_room,
        )


def fly(
    spec: MissionSpec,
    autopilot_settings: AutopilotSettings | None = None,
    marker_settings: MarkerSettings | None = None,
    progress: Callable[[float, Autopilot], None] | None = None,
    clock: Callable[[], float] = time.thread_time,
) -> MissionResult:
    """Fly one mission to its end; ``clock`` times the autopilot's work per frame (by default the
    thread's CPU time: a shared machine's load stretches the wall time, not the work)."""
    run = MissionRun(spec, autopilot_settings, marker_settings, clock)
    while run.step():
        if progress is not None:
            progress(run.t, run.pilot)
    return run.result()
