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


def fly(
    spec: MissionSpec,
    autopilot_settings: AutopilotSettings | None = None,
    marker_settings: MarkerSettings | None = None,
    progress: Callable[[float, Autopilot], None] | None = None,
    clock: Callable[[], float] = time.perf_counter,
) -> MissionResult:
    """Fly one mission; ``clock`` times the autopilot's work per frame."""
    autopilot_settings = autopilot_settings or AutopilotSettings()
    marker_settings = marker_settings or MarkerSettings()
    for name, marker in (("target", spec.target), ("start", spec.start_marker)):
        if marker is not None and not 0 <= marker < MARKER_COLS * MARKER_ROWS:
            raise UsageError(f"--{name} {marker}: the field's markers are 0-{MARKER_COLS * MARKER_ROWS - 1}")
    rng = np.random.default_rng(spec.seed)
    centres = marker_world_centres()
    scene = build_scenario("marker-field", SimOptions(duration_s=1.0)).scene
    camera = mission_camera(spec.resolution)
    renderer = Renderer(camera, scene)
    detector = MarkerDetector(camera, marker_settings)
    start = centres[spec.start_marker] + rng.normal(0, 0.01, 2)
    vehicle = Quadrotor(spec.vehicle, rng, start)
    pilot = Autopilot(autopilot_settings, marker_settings, landing_target=spec.target, marker_map=spec.prior_map)
    if spec.hover_s is not None:
        pilot.hover(spec.hover_s)
    commands = sorted(spec.commands, key=lambda c: c[0])
    frame_dt = 1.0 / spec.fps
    times, truth, estimated, heights, states, mapped, frame_ms, issued = [], [], [], [], [], [], [], []
    noise = np.empty((camera.height, camera.width), np.float32)
    cv2.setRNGSeed(spec.seed)
    command = Command(0.0, State.GROUND, np.zeros(2), np.zeros(2), 0.0, False)
    left_room = False
    t = 0.0
    while t <= spec.duration_s:
        while commands and commands[0][0] <= t:
            pilot.command(t, commands.pop(0)[1])
        s = vehicle.state
        R = s.rotation()
        down = R @ np.array([0.0, 0.0, -1.0])
        distance = ray_distance(scene, s.position, down)
        reading = distance + rng.normal(0, spec.range.noise_m) if distance <= spec.range.max_range_m and not _in(spec.range_gaps, t) else float("nan")
        observations = None
        elapsed = 0.0
        if not _in(spec.frame_gaps, t):
            T = np.eye(4)
            T[:3, :3] = R @ DOWNWARD
            T[:3, 3] = s.position
            image = renderer.render(T).astype(np.float32)
            cv2.randn(noise, 0.0, IMAGE_NOISE_SIGMA)
            frame = np.clip(image + noise, 0, 255).astype(np.uint8)
            began = clock()
            observations = detector.detect(frame)
            command = pilot.step(t, observations, reading)
            elapsed = clock() - began
            frame_ms.append(elapsed * 1000.0)
        else:
            command = pilot.step(t, None, reading)
        issued.append(command)
        times.append(t)
        truth.append(s.position.copy())
        estimated.append(pilot.position.copy() if pilot.position is not None else np.full(3, np.nan))
        heights.append(reading)
        states.append(pilot.state.value)
        mapped.append(len(set(pilot.marker_map.poses) & set(centres)))
        if progress is not None:
            progress(t, pilot)
        if pilot.state == State.LANDED:
            break
        for _ in range(PHYSICS_STEPS_PER_FRAME):
            vehicle.step(command.tilt_body, command.climb_m_s, command.motors, frame_dt / PHYSICS_STEPS_PER_FRAME)
        if np.any(np.abs(vehicle.state.position[:2]) > ROOM_HALF_M - VEHICLE_RADIUS_M):
            left_room = True
            pilot.log("left_room", f"the vehicle reached the room's wall at {vehicle.state.position[:2].round(2).tolist()}")
            break
        t = round(t + frame_dt, 9)
    root = pilot.marker_map.root
    origin = np.array([*centres[root], 0.0]) if root in centres else np.zeros(3)
    return MissionResult(
        spec,
        np.array(times),
        np.array(truth),
        np.array(estimated),
        np.array(heights),
        states,
        np.array(mapped),
        np.array(frame_ms),
        issued,
        pilot,
        centres,
        origin,
        left_room,
    )
