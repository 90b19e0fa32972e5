"""The scenes of the papers as simulation scenarios (each documented in docs/simulator.md).

A scenario is the world (textured surfaces), the vehicle's motion, the camera and how it is
mounted, the geodetic origin and which sensors the vehicle carries.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
from pydantic import BaseModel, ConfigDict, Field
from scipy.spatial.transform import Rotation

from evp.calib.profiles import load_profile
from evp.errors import UsageError
from evp.sim import paths, road
from evp.sim.motion import SplineMotion, car_attitude, heading_from_velocity, multirotor_attitude
from evp.sim.sensors import BaroConfig, GpsConfig, ImuConfig, RangeConfig, WheelConfig, WifiConfig
from evp.sim.textures import TEXTURE_KINDS, image_texture, marker_field_texture, procedural_texture
from evp.sim.world import Scene, TexturedQuad, box_quads
from evp.types import CameraModel, LensModel

# camera optical axes (columns x, y, z) in the body frame (x forward, y left, z up)
DOWNWARD = np.array([[0.0, -1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])  # image top = forward
FORWARD = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])
# Kannala-Brandt k1..k4 of the simulated fisheye: TUM VI's cam0 (a 195-degree lens, Schubert et
# al. 2018), a real lens's mild departure from the ideal equidistant projection
FISHEYE_COEFFICIENTS = (0.0034823894022493434, 0.0007150348452162257, -0.0020532361418706202, 0.00020293673591811182)


class SimOptions(BaseModel):
    """Everything ``evp sim`` can be told; None means the scenario's own default."""

    model_config = ConfigDict(extra="forbid")

    duration_s: float | None = Field(None, ge=0.15, description="seconds (at least 0.15: four motion samples; None: the scenario's)")
    seed: int = 0
    fps: float = Field(30.0, gt=0, le=240)
    camera: str | None = Field(None, description="camera profile shipped with EVP (evp camera list), as evp camera and camera.profile name them")
    texture: str | None = Field(None, description="rich, low, floor, wall, or image file(s) separated by commas")
    altitude_m: float | None = Field(None, gt=0)
    speed_m_s: float | None = Field(None, gt=0)
    pattern: str | None = Field(None, pattern="^(lawnmower|loops|free)$")
    area_m: tuple[float, float] | None = None
    ground_half_m: float | None = Field(
        None,
        gt=0,
        description="drone-flight: half the side of the textured ground, m (None: the flown path's extent plus a footprint, at least 60); the texture depends on it, so flights over one world give the same",
    )
    takeoff_m: tuple[float, float] = Field(
        (0.0, 0.0),
        description="drone-flight: take-off point (x, y) in m from the world's origin; with the same ground_half_m the world (ground, relief, GPS origin) stays the same: a second flight over the area from elsewhere",
    )
    gimbal: bool = Field(False, description="camera held level (nadir) by a gimbal instead of fixed to the body")
    relief: bool = Field(True, description="buildings and trees on the ground (drone scenarios)")
    distortion: bool = True
    lens: str = Field("pinhole", pattern="^(pinhole|fisheye)$", description="pinhole (the preset's lens) or fisheye (equidistant, at the preset's resolution)")
    fisheye_fov_deg: float = Field(
        150.0, ge=120, le=180, description="fisheye: diagonal field of view in degrees (corner to corner, so every ray is within 90 degrees of the axis)"
    )
    exposure_s: float = Field(0.004, ge=0, description="motion blur: the image integrates the motion over this time")
    gain_variation: float = Field(0.08, ge=0, le=0.9, description="relative exposure change amplitude")
    noise_sigma: float = Field(2.0, ge=0, description="read noise (grey levels); shot noise is added too")
    rolling_shutter_s: float = Field(0.0, ge=0, description="row readout time top to bottom; 0 = global shutter")
    drop_probability: float = Field(0.0, ge=0, lt=1)
    image_format: str = Field("jpg", pattern="^(jpg|png)$", description="jpg (quality 95, what a phone streams) or png (lossless, 5x slower to write)")
    imu: ImuConfig = ImuConfig()
    gps: GpsConfig = GpsConfig()
    baro: BaroConfig = BaroConfig()
    wheel: WheelConfig = WheelConfig()
    range: RangeConfig = RangeConfig()
    wifi: WifiConfig = WifiConfig()


@dataclass
class Scenario:
    name: str
    camera: CameraModel
    R_body_cam: np.ndarray
    t_body_cam: np.ndarray
    motion: SplineMotion
    scene: Scene
    origin: tuple[float, float, float]  # latitude, longitude, altitude of the world origin
    sensors: tuple[str, ...]  # imu, gps, baro, wheel, range, wifi
    gimbal: bool = False
    access_points: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    notes: list[str] = field(default_factory=list)

    @property
    def T_body_cam(self) -> np.ndarray:
        T = np.eye(4)
        T[:3, :3] = self.R_body_cam
        T[:3, 3] = self.t_body_cam
        return T

    def camera_poses(self, times: np.ndarray) -> np.ndarray:
        """(N, 4, 4) T_world_cam; with a gimbal only the heading of the body turns the camera."""
        state = self.motion.state(times)
        body = state.poses()
        if self.gimbal:
            yaw = state.rotation.as_euler("ZYX")[:, 0]
            body[:, :3, :3] = Rotation.from_euler("Z", yaw[:, None]).as_matrix()
        return body @ self.T_body_cam


def _camera(options: SimOptions, default: str) -> CameraModel:
    name = options.camera or default
    camera = load_profile(name)  # one list of names for evp sim, evp camera and camera.profile
    if options.lens == "fisheye":
        return fisheye_camera(camera.width, camera.height, options.fisheye_fov_deg, FISHEYE_COEFFICIENTS if options.distortion else (0.0,) * 4, name)
    if not options.distortion:
        camera = CameraModel(camera.width, camera.height, camera.fx, camera.fy, camera.cx, camera.cy, name=camera.name)
    return camera


def fisheye_camera(width: int, height: int, diagonal_fov_deg: float, coefficients: tuple[float, ...], preset: str) -> CameraModel:
    """An equidistant fisheye centred on the image whose corner pixels' outer corners see
    ``diagonal_fov_deg`` / 2 off the axis: its focal length puts the half diagonal at theta_d."""
    k1, k2, k3, k4 = coefficients
    unit = CameraModel(width, height, 1.0, 1.0, 0.0, 0.0, k1, k2, k3=k3, k4=k4, lens=LensModel.EQUIDISTANT)
    half = np.radians(diagonal_fov_deg / 2)
    theta_d = unit.project(np.array([[np.sin(half), 0.0, np.cos(half)]]))[0, 0]  # on the unit focal length's image
    focal = float(np.hypot(width, height) / 2 / theta_d)
    return replace(unit, fx=focal, fy=focal, cx=(width - 1) / 2, cy=(height - 1) / 2, name=f"{preset}_fisheye{diagonal_fov_deg:g}")


def _ground(options: SimOptions, default_kind: str, half_extent: float, metres_per_texel: float) -> TexturedQuad:
    size = 2 * half_extent
    spec = options.texture or default_kind
    if spec in TEXTURE_KINDS:
        texels = min(12000, int(size / metres_per_texel))
        texture = procedural_texture(spec, (size, size), size / texels, options.seed)
    else:
        files = [Path(p) for p in spec.split(",")]
        texture = image_texture(files)
        scale = size / max(texture.shape)
        texture = texture[: int(size / scale), : int(size / scale)]
        return TexturedQuad([-half_extent, -half_extent, 0], [1, 0, 0], [0, 1, 0], texture.shape[1] * scale, texture.shape[0] * scale, texture, scale, "ground")
    return TexturedQuad([-half_extent, -half_extent, 0], [1, 0, 0], [0, 1, 0], size, size, texture, size / texture.shape[1], "ground")


LANDING_GEAR_M = 0.3  # body origin above the ground when landed


def _multirotor(times: np.ndarray, positions: np.ndarray) -> SplineMotion:
    """Attitude of a multirotor flying these positions (tilted by its acceleration, nose along the
    path); positions are of the body origin above the landing gear, so landed means z = 0."""
    positions = positions + np.array([0.0, 0.0, LANDING_GEAR_M])
    rough = SplineMotion(times, positions, Rotation.identity(len(times)))
    state = rough.state(times)
    yaw = paths.smooth(heading_from_velocity(state.velocity)[:, None], 1.0)[:, 0]
    return SplineMotion(times, positions, multirotor_attitude(state.acceleration, yaw))


def _relief(rng: np.random.Generator, half_extent: float, keep_clear: float, seed: int) -> list[TexturedQuad]:
    """Buildings (6-15 m) and trees (3-8 m) scattered outside the take-off area."""
    quads = []
    facade = procedural_texture("wall", (20.0, 20.0), 0.1, seed + 1)
    canopy = procedural_texture("rich", (10.0, 10.0), 0.05, seed + 2)
    count = int((2 * half_extent) ** 2 / 2500) + 4
    for i in range(count):
        centre = rng.uniform(-half_extent * 0.8, half_extent * 0.8, 2)
        if np.linalg.norm(centre) < keep_clear:
            continue
        if i % 3 == 0:
            size = rng.uniform(8, 20, 2)
            height = rng.uniform(6, 15)
            quads += box_quads([*centre, height / 2], [*size, height], facade, 0.1, f"building{i}")
        else:
            size = rng.uniform(3, 6)
            height = rng.uniform(3, 8)
            quads += box_quads([*centre, height / 2], [size, size, height], canopy, 0.05, f"tree{i}")
    return quads


def drone_flight(options: SimOptions) -> Scenario:
    """Seed 002: take-off, climb to 60 m (30-110), survey at 6 m/s (4-8), land; 300 s by default."""
    rng = np.random.default_rng(options.seed)
    camera = _camera(options, "nexus5x_640x380")
    altitude = options.altitude_m or 60.0
    speed = options.speed_m_s or 6.0
    duration = options.duration_s or 300.0
    climb = 3.0
    footprint = altitude * camera.width / camera.fx
    pattern = options.pattern or "lawnmower"
    cruise_time = max(10.0, duration - 2 * altitude / climb - 10.0)
    if pattern == "lawnmower":
        width = options.area_m[0] if options.area_m else min(250.0, max(40.0, speed * cruise_time / 6))
        height = options.area_m[1] if options.area_m else width * 0.6
        horizontal = paths.lawnmower(width, height, 0.6 * footprint)
    elif pattern == "loops":
        width, height = options.area_m or (120.0, 80.0)
        horizontal = paths.loops(width, height)
    else:
        width, height = options.area_m or (200.0, 150.0)
        horizontal = paths.random_waypoints(rng, width, height, 12)
    route = np.column_stack([horizontal, np.full(len(horizontal), altitude)])
    takeoff_x, takeoff_y = options.takeoff_m
    points = np.vstack([[takeoff_x, takeoff_y, 0], [takeoff_x, takeoff_y, altitude], route])
    samples = np.vstack([paths.hold(points[0], 2.0), paths.walk_polyline(points, [climb] + [speed] * (len(points) - 2))])
    samples = paths.fit_duration(samples, duration - altitude / climb - 2.0)
    landing = paths.walk_polyline(np.array([samples[-1], [*samples[-1, :2], 0.0]]), climb)
    samples = paths.fit_duration(paths.smooth(np.vstack([samples, landing, paths.hold([*samples[-1, :2], 0.0], 2.0)]), 1.5), duration)
    times = np.arange(len(samples)) * paths.SAMPLE_DT
    half = options.ground_half_m or max(np.abs(samples[:, :2]).max() + footprint, 60.0)
    ground = _ground(options, "rich", half, max(0.04, altitude / camera.fx / 1.5))
    quads = [ground] + (_relief(rng, half, 25.0, options.seed) if options.relief else [])
    return Scenario(
        "drone-flight",
        camera,
        DOWNWARD,
        np.array([0.0, 0.0, -0.08]),
        _multirotor(times, samples),
        Scene(quads, background=200),
        (43.7238, 10.3966, 4.0),
        ("imu", "gps", "baro"),
        gimbal=options.gimbal,
        notes=[f"{pattern} over {width:.0f} x {height:.0f} m at {altitude:.0f} m, {speed:.1f} m/s"],
    )


def _seed000_loops(options: SimOptions, name: str, area: tuple[float, float], texture: str, altitude: float) -> Scenario:
    camera = _camera(options, "nexus5x_640x380")
    altitude = options.altitude_m or altitude
    speed = options.speed_m_s or 2.0
    duration = options.duration_s or 150.0
    width, height = options.area_m or area
    horizontal = paths.loops(width, height, turns=2)
    route = np.column_stack([horizontal, np.full(len(horizontal), altitude)])
    points = np.vstack([[0, 0, 0], [0, 0, altitude], route])
    samples = paths.walk_polyline(points, [1.5] + [speed] * (len(points) - 2))
    samples = paths.fit_duration(paths.smooth(np.vstack([paths.hold(points[0], 2.0), samples]), 1.0), duration)
    times = np.arange(len(samples)) * paths.SAMPLE_DT
    half = max(width, height) / 2 + altitude * 1.5 + 10
    ground = _ground(options, texture, half, max(0.01, altitude / camera.fx / 1.5))
    return Scenario(
        name,
        camera,
        DOWNWARD,
        np.array([0.0, 0.0, -0.08]),
        _multirotor(times, samples),
        Scene([ground], background=200),
        (3.3752, -76.5331, 980.0),
        ("imu", "gps", "baro"),
        gimbal=options.gimbal,
        notes=[f"seed 000 manual-like loops over {width} x {height} m at {altitude} m ({texture} texture)"],
    )


def drone_field_loops(options: SimOptions) -> Scenario:
    """Seed 000's football-field flight: loops over 27 x 28 m of a mown pitch (altitude assumed 15 m)."""
    return _seed000_loops(options, "drone-field-loops", (27.0, 28.0), "pitch", 15.0)


def drone_square_loops(options: SimOptions) -> Scenario:
    """Seed 000's paved-square flight: loops over 27.5 x 9 m, rich texture (altitude assumed 12 m)."""
    return _seed000_loops(options, "drone-square-loops", (27.5, 9.0), "rich", 12.0)


def circle_indoor(options: SimOptions) -> Scenario:
    """Seed 000's indoor test: the phone on a monopod, camera down ~1.2 m above the floor, carried by
    hand around a 2.2 m diameter circle at ~0.35 m/s, with hand-held jitter."""
    rng = np.random.default_rng(options.seed)
    camera = _camera(options, "nexus5x_640x380")
    duration = options.duration_s or 60.0
    speed = options.speed_m_s or 0.35
    height = options.altitude_m or 1.2
    radius = 1.1
    times = np.arange(0.0, duration + 1e-9, paths.SAMPLE_DT)
    walking = np.clip(times - 2.0, 0.0, None)
    angle = speed * walking / radius
    jitter = paths.smooth(rng.normal(0, 0.03, (len(times), 3)), 0.4) * 4
    positions = np.column_stack([radius * np.cos(angle) - radius, radius * np.sin(angle), np.full(len(times), height)]) + jitter * [1, 1, 0.5]
    yaw = angle + np.pi / 2
    tilt = paths.smooth(rng.normal(0, 0.02, (len(times), 2)), 0.5) * 3
    rotation = Rotation.from_euler("ZYX", np.column_stack([yaw, tilt[:, 0], tilt[:, 1]]))
    ground = _ground(options, "floor", 6.0, 0.004)
    walls = box_quads([0, 0, 1.5], [12, 12, 3], procedural_texture("wall", (12, 3), 0.01, options.seed), 0.01, "room")
    return Scenario(
        "circle-indoor",
        camera,
        DOWNWARD,
        np.zeros(3),
        SplineMotion(times, positions, rotation),
        Scene([ground] + walls),
        (3.3752, -76.5331, 980.0),
        ("imu", "baro", "wifi"),
        access_points=np.array([[2.0, 3.0, 2.5], [-3.0, 1.0, 2.5], [0.5, -3.5, 2.5]]),
        notes=["seed 000 indoor circle, 2.2 m diameter"],
    )


def _furnished_lab(options: SimOptions, rng: np.random.Generator) -> list[TexturedQuad]:
    """Seed 001's 6 x 5 x 2.5 m lab: textured floor and walls, five boxes of furniture."""
    floor = _ground(options, "floor", 3.5, 0.004)
    wall_texture = procedural_texture("wall", (22.0, 2.5), 0.01, options.seed)
    quads = [floor] + box_quads([0, 0, 1.25], [6.0, 5.0, 2.5], wall_texture, 0.01, "room", skip_bottom=True)
    for i, (x, y) in enumerate([(0.0, -2.0), (2.6, 0.0), (-2.6, 0.2), (0.0, 2.1), (0.9, 0.9)]):
        size = rng.uniform(0.3, 0.7, 3)
        quads += box_quads([x, y, size[2] / 2], size, procedural_texture("wall", (2.0, 2.0), 0.005, options.seed + 10 + i), 0.005, f"object{i}")
    return quads


def wheel_robot_room(options: SimOptions) -> Scenario:
    """Seed 001: a wheel robot carrying a phone (camera forward, 0.2 m up) drives a loop with turns
    through a 6 x 5 m lab with furniture, at 0.3 m/s; wheel encoders + gyro, WiFi from 3 APs."""
    rng = np.random.default_rng(options.seed)
    camera = _camera(options, "nexus5x_640x380")
    duration = options.duration_s or 60.0
    speed = options.speed_m_s or 0.3
    corners = np.array([[-1.8, -1.2], [1.8, -1.2], [1.8, 1.2], [0.0, 0.3], [-1.8, 1.2], [-1.8, -1.2]])
    loop = np.vstack([corners] * 10)
    samples = paths.walk_polyline(np.column_stack([loop, np.zeros(len(loop))]), speed)
    samples = paths.fit_duration(paths.smooth(np.vstack([paths.hold(samples[0], 2.0), samples]), 1.2), duration)
    times = np.arange(len(samples)) * paths.SAMPLE_DT
    rough = SplineMotion(times, samples, Rotation.identity(len(times))).state(times)
    yaw = paths.smooth(heading_from_velocity(rough.velocity, min_speed=0.05)[:, None], 0.5)[:, 0]
    motion = SplineMotion(times, samples, Rotation.from_euler("Z", yaw[:, None]))
    quads = _furnished_lab(options, rng)
    pitch_up = Rotation.from_euler("x", -5, degrees=True).as_matrix()
    return Scenario(
        "wheel-robot-room",
        camera,
        FORWARD @ pitch_up,
        np.array([0.05, 0.0, 0.2]),
        motion,
        Scene(quads),
        (25.0330, 121.5654, 10.0),
        ("imu", "wheel", "wifi"),
        access_points=np.array([[2.8, 2.3, 2.0], [-2.8, 2.3, 2.0], [0.0, -2.3, 2.0]]),
        notes=["seed 001 wheel robot in a lab room"],
    )


def marker_field(options: SimOptions) -> Scenario:
    """Seed 003: a quadcopter with a phone looking down flies 0.5 m above a floor of 99 ArUco
    markers (98 mm, 98 mm gaps, 1.86 x 2.25 m) in a 4 x 4 m room, exploring at 0.2 m/s; sonar."""
    camera = _camera(options, "nexus5x_640x380")
    duration = options.duration_s or 60.0
    height = options.altitude_m or 0.5
    speed = options.speed_m_s or 0.2
    texture, mpt, _ = marker_field_texture()
    width, depth = texture.shape[1] * mpt, texture.shape[0] * mpt
    markers = TexturedQuad([-width / 2, -depth / 2, 0.001], [1, 0, 0], [0, 1, 0], width, depth, texture, mpt, "markers")
    floor = _ground(options, "floor", 2.0, 0.004)
    walls = box_quads([0, 0, 1.5], [4.0, 4.0, 3.0], procedural_texture("wall", (16, 3), 0.01, options.seed), 0.01, "room")
    horizontal = paths.lawnmower(width * 0.7, depth * 0.7, 0.35)
    route = np.column_stack([horizontal, np.full(len(horizontal), height)])
    points = np.vstack([[0, 0, 0], [0, 0, height], route])
    samples = paths.walk_polyline(points, [0.3] + [speed] * (len(points) - 2))
    samples = paths.fit_duration(paths.smooth(np.vstack([paths.hold(points[0], 1.0), samples]), 0.8), duration)
    times = np.arange(len(samples)) * paths.SAMPLE_DT
    return Scenario(
        "marker-field",
        camera,
        DOWNWARD,
        np.zeros(3),
        _multirotor(times, samples),
        Scene([markers, floor] + walls),
        (48.2082, 16.3738, 180.0),
        ("imu", "range"),
        notes=["seed 003 marker floor"],
    )


def hover_drift(options: SimOptions) -> Scenario:
    """A drone holding position at 20 m while gusts push it around (a random walk of a few metres)."""
    rng = np.random.default_rng(options.seed)
    camera = _camera(options, "nexus5x_640x380")
    duration = options.duration_s or 60.0
    altitude = options.altitude_m or 20.0
    climb = paths.walk_polyline(np.array([[0, 0, 0], [0, 0, altitude]]), 2.0)
    hover_count = int(round(duration / paths.SAMPLE_DT)) + 1
    drift = paths.smooth(np.cumsum(rng.normal(0, 0.05, (hover_count, 3)), axis=0), 2.0) * [1, 1, 0.3]
    samples = paths.fit_duration(paths.smooth(np.vstack([paths.hold([0, 0, 0], 1.0), climb, climb[-1] + drift]), 0.8), duration)
    times = np.arange(len(samples)) * paths.SAMPLE_DT
    ground = _ground(options, "rich", 80.0, max(0.02, altitude / camera.fx / 1.5))
    return Scenario(
        "hover-drift",
        camera,
        DOWNWARD,
        np.array([0.0, 0.0, -0.08]),
        _multirotor(times, samples),
        Scene([ground], background=200),
        (43.7238, 10.3966, 4.0),
        ("imu", "gps", "baro"),
        gimbal=options.gimbal,
        notes=["hovering with wind drift"],
    )


PAN_ARM_M = 0.35  # phone ahead of the turning body's axis: held out at chest height
PAN_HALF_ANGLE_DEG = 80.0  # the sweep, either side of the start's view
PAN_STILL_S = 1.0  # held still before the pan begins


def handheld_pan(options: SimOptions) -> Scenario:
    """Rotation-dominant hand-held video: a person standing off-centre in seed 001's lab turns
    on the spot to pan the room, phone held forward 0.35 m from the body's axis at 1.4 m, sweeping
    80 degrees either way and back (the hand moves at --speed, 0.3 m/s by default: ~50 degrees/s
    at the fastest), with a hand's tremor and tilt. The translation is only the phone's arc, a few
    centimetres between frames against walls 2-4 m away: the parallax a monocular start and new
    map points need comes slowly, while the view turns fast."""
    rng = np.random.default_rng(options.seed)
    camera = _camera(options, "nexus5x_640x380")
    duration = options.duration_s or 20.0
    speed = options.speed_m_s or 0.3
    height = options.altitude_m or 1.4
    times = np.arange(0.0, duration + 1e-9, paths.SAMPLE_DT)
    half = np.radians(PAN_HALF_ANGLE_DEG)
    period = 2 * np.pi * half * PAN_ARM_M / speed  # the sine sweep at its fastest moves the hand at `speed`
    turning = np.clip(times - PAN_STILL_S, 0.0, None)
    yaw = np.radians(rng.uniform(0, 360)) + half * np.sin(2 * np.pi * turning / period)
    standing = np.array([-0.8, 0.4]) + rng.uniform(-0.3, 0.3, 2)
    tremor = paths.smooth(rng.normal(0, 0.01, (len(times), 3)), 0.3) * 3
    positions = np.column_stack([standing + PAN_ARM_M * np.column_stack([np.cos(yaw), np.sin(yaw)]), np.full(len(times), height)]) + tremor
    tilt = paths.smooth(rng.normal(0, 0.02, (len(times), 2)), 0.5) * 3
    rotation = Rotation.from_euler("ZYX", np.column_stack([yaw, tilt[:, 0], tilt[:, 1]]))
    return Scenario(
        "handheld-pan",
        camera,
        FORWARD,
        np.zeros(3),
        SplineMotion(times, positions, rotation),
        Scene(_furnished_lab(options, rng)),
        (25.0330, 121.5654, 10.0),
        ("imu",),
        notes=[f"hand-held pan of +-{PAN_HALF_ANGLE_DEG:.0f} degrees, phone {PAN_ARM_M} m from the turning axis, hand at up to {speed:.2f} m/s"],
    )


MAX_LATERAL_ACCEL_M_S2 = 3.0  # a comfortable curve for a driver: the road's tightest radius is v^2 / this


def road_drive(options: SimOptions) -> Scenario:
    """A car phone on the windscreen (camera forward, 1.5 m up) driving the right lane of a curving
    town road at 20 m/s (10-30), past buildings, trees and parked cars, with hills far away; the
    speed wanders by 10 %. KITTI's camera (car_1241x376); IMU, GPS and wheel speed (OBD)."""
    rng = np.random.default_rng(options.seed)
    camera = _camera(options, "car_1241x376")
    speed = options.speed_m_s or 20.0
    duration = options.duration_s or 60.0
    height = options.altitude_m or 1.5
    times = np.arange(0.0, duration + 1e-9, paths.SAMPLE_DT)
    pace = speed * (1.0 + 0.1 * np.sin(2 * np.pi * times / 25.0 + rng.uniform(0, 2 * np.pi)))
    start = 30.0  # metres of road behind the start: the first view is of road, not of its end
    travelled = start + np.concatenate([[0.0], np.cumsum((pace[1:] + pace[:-1]) / 2) * paths.SAMPLE_DT])
    min_radius = max(100.0, speed**2 / MAX_LATERAL_ACCEL_M_S2)
    line = road.centreline(rng, travelled[-1] + 300.0, min_radius)
    xy, yaw = line.at(travelled, -road.LANE_WIDTH_M / 2)
    positions = np.column_stack([xy, np.full(len(times), height)])
    acceleration = SplineMotion(times, positions, Rotation.identity(len(times)), ends="natural").state(times).acceleration
    shake = paths.smooth(rng.normal(0.0, np.radians(0.3), (len(times), 2)), 0.15)  # road surface, ~0.1 degree
    motion = SplineMotion(times, positions, car_attitude(acceleration, yaw, shake), ends="natural")
    quads = road.road_surface(line, camera, height, options.seed) + road.roadside(line, camera, rng, options.seed) + road.far_away(line, rng, options.seed)
    return Scenario(
        "road-drive",
        camera,
        FORWARD,
        np.zeros(3),
        motion,
        Scene(quads, background=215),
        (49.0069, 8.4037, 115.0),
        ("imu", "gps", "wheel"),
        notes=[f"town road, {line.length:.0f} m with curves of radius >= {min_radius:.0f} m, {speed:.1f} m/s, camera {height} m up"],
    )


SCENARIOS: dict[str, Callable[[SimOptions], Scenario]] = {
    "drone-flight": drone_flight,
    "drone-field-loops": drone_field_loops,
    "drone-square-loops": drone_square_loops,
    "circle-indoor": circle_indoor,
    "wheel-robot-room": wheel_robot_room,
    "marker-field": marker_field,
    "hover-drift": hover_drift,
    "road-drive": road_drive,
    "handheld-pan": handheld_pan,
}


def build_scenario(name: str, options: SimOptions) -> Scenario:
    if name not in SCENARIOS:
        raise UsageError(f"unknown scenario {name!r}; choose one of {', '.join(SCENARIOS)}")
    return SCENARIOS[name](options)
