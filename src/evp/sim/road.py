"""A town road for the ``road-drive`` scenario: a curving centreline, the asphalt with its lane
markings, the verges, what stands along the road (buildings, trees, parked cars) and hills far away.

Geometry (metres, lateral offsets positive to the left of the direction of travel): two 3.5 m lanes
with edge lines, a 2.5 m parking strip on each side (asphalt to 6 m), verges (paving) to 40 m,
parked cars on the strips, trees 7-9 m out, building fronts 12-30 m out, and hills 400-1200 m
beyond the route; everything else is a coarse field under a sky-coloured background.

Only what a forward camera on the road can see is built: building fronts and their ends facing
the oncoming car (not their backs, far ends or roofs, all above or behind what a camera 1.5 m up
sees), and each texture is sized to the finest footprint a pixel has on it where the camera first
sees it (``upright_texel``, ``ground_texel``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.ndimage import gaussian_filter1d

from evp.sim import textures
from evp.sim.world import TexturedQuad
from evp.types import CameraModel

LANE_WIDTH_M = 3.5  # a European two-lane town road
ASPHALT_HALF_WIDTH_M = 6.0  # two lanes and a 2.5 m parking strip on each side
VERGE_OUTER_M = 40.0
LINE_WIDTH_M = 0.15
DASH_M, DASH_GAP_M = 3.0, 6.0  # the centre line's dashes (German urban: 3 m lines, 6 m gaps)
SEGMENT_M = 10.0  # straight pieces of road this long: a chord of a 100 m curve is 0.13 m off the arc, and
# the renderer picks one mip level per piece, so shorter pieces keep the near road sharper
MIN_TEXEL_M = 0.02  # nearer texels than this would be smeared by motion blur anyway (20 m/s x 4 ms = 8 cm)
SAMPLE_M = 0.5


@dataclass(frozen=True)
class Centreline:
    """The road's centre, sampled every ``SAMPLE_M`` metres of arc length."""

    xy: np.ndarray  # (N, 2)
    heading: np.ndarray  # (N,) radians from east, unwrapped

    @property
    def length(self) -> float:
        return (len(self.xy) - 1) * SAMPLE_M

    def at(self, s: np.ndarray | float, lateral: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
        """Points ``lateral`` metres left of the centre at arc lengths ``s``, and the heading there."""
        s = np.atleast_1d(np.asarray(s, dtype=float))
        grid = np.arange(len(self.xy)) * SAMPLE_M
        heading = np.interp(s, grid, self.heading)
        xy = np.column_stack([np.interp(s, grid, self.xy[:, 0]), np.interp(s, grid, self.xy[:, 1])])
        return xy + lateral * np.column_stack([-np.sin(heading), np.cos(heading)]), heading


def centreline(rng: np.random.Generator, length_m: float, min_radius_m: float) -> Centreline:
    """Straights of 40-150 m and curves of 1-3 times ``min_radius_m`` turning 20-50 degrees, with
    clothoid-like transitions (the curvature smoothed over 15 m). A curve turns back towards the
    start heading once the road points more than 20 degrees away from it, so the road heads east
    overall and never crosses itself."""
    s = np.arange(0.0, length_m + SAMPLE_M, SAMPLE_M)
    curvature = np.zeros(len(s))
    position, heading = rng.uniform(20.0, 80.0), 0.0
    while position < length_m:
        radius = rng.uniform(1.0, 3.0) * min_radius_m
        turn = np.radians(rng.uniform(20.0, 50.0))
        sign = -np.sign(heading) if abs(heading) > np.radians(20.0) else rng.choice([-1.0, 1.0])
        arc = radius * turn
        curvature[(s >= position) & (s < position + arc)] = sign / radius
        heading += sign * turn
        position += arc + rng.uniform(40.0, 150.0)
    curvature = gaussian_filter1d(curvature, 15.0 / SAMPLE_M, mode="nearest")
    headings = np.concatenate([[0.0], np.cumsum(curvature[:-1]) * SAMPLE_M])
    steps = np.column_stack([np.cos(headings[:-1]), np.sin(headings[:-1])]) * SAMPLE_M
    return Centreline(np.vstack([[0.0, 0.0], np.cumsum(steps, axis=0)]), headings)


def upright_texel(camera: CameraModel, lateral_m: float) -> float:
    """Texel size a pixel resolves on an upright surface ``lateral_m`` from the road's centre: the
    camera (in the right lane) first sees it at the edge of its field of view."""
    half_fov = np.arctan(max(camera.cx, camera.width - camera.cx) / camera.fx)
    return max(MIN_TEXEL_M, (lateral_m - LANE_WIDTH_M / 2) / np.sin(half_fov) / camera.fx)


def ground_texel(camera: CameraModel, camera_height: float, nearest_m: float) -> float:
    """Texel size a pixel resolves on the ground ``nearest_m`` away at the closest: seen at a grazing
    angle, a pixel covers d^2 / (h fx) along the line of sight, and the renderer picks its mip level
    by that length."""
    return max(MIN_TEXEL_M, nearest_m**2 / (camera_height * camera.fx))


def _upright(texture: np.ndarray) -> np.ndarray:
    """An image-like texture (row 0 at the top) for a quad whose v axis points up."""
    return np.ascontiguousarray(texture[::-1])


def _vertical_quad(origin_xy, along_xy, width: float, bottom: float, height: float, texture: np.ndarray, name: str) -> TexturedQuad:
    return TexturedQuad([*origin_xy, bottom], [*along_xy, 0.0], [0, 0, 1], width, height, _upright(texture), width / texture.shape[1], name)


def _paint_markings(texture: np.ndarray, metres_per_texel: float, start_s: float) -> None:
    """Edge lines at +-3.5 m and the dashed centre line, in place; rows run from the right edge
    (-6 m) to the left, columns along the road from arc length ``start_s``."""
    rows, cols = texture.shape
    s = start_s + (np.arange(cols) + 0.5) * metres_per_texel
    lateral = -ASPHALT_HALF_WIDTH_M + (np.arange(rows) + 0.5) * metres_per_texel
    paint = np.zeros((rows, cols), bool)
    paint[np.abs(np.abs(lateral) - LANE_WIDTH_M) < LINE_WIDTH_M / 2] = True
    centre = np.abs(lateral) < LINE_WIDTH_M / 2
    paint[np.ix_(centre, (s % (DASH_M + DASH_GAP_M)) < DASH_M)] = True
    texture[paint] = 225


def road_surface(line: Centreline, camera: CameraModel, camera_height: float, seed: int) -> list[TexturedQuad]:
    """Asphalt and verges as straight pieces along the centreline. Neighbouring pieces overlap by
    what the turn between them opens on the outside of a curve; alternate pieces sit 1 mm lower so
    that in the overlap the upper one always wins (no flicker between coplanar quads)."""
    road_texel = ground_texel(camera, camera_height, camera_height * camera.fy / (camera.height - camera.cy))  # the nearest asphalt in view
    half_fov = np.arctan(max(camera.cx, camera.width - camera.cx) / camera.fx)
    verge_texel = ground_texel(camera, camera_height, (ASPHALT_HALF_WIDTH_M - LANE_WIDTH_M / 2) / np.sin(half_fov))
    ends = np.arange(0.0, line.length, SEGMENT_M)
    points, _ = line.at(np.append(ends, line.length))
    chords = np.diff(points, axis=0)
    angles = np.arctan2(chords[:, 1], chords[:, 0])
    turn = np.abs(np.diff(np.unwrap(angles), prepend=angles[0], append=angles[-1]))
    quads = []
    for k, (start, chord, angle) in enumerate(zip(points[:-1], chords, angles)):
        along = np.array([np.cos(angle), np.sin(angle)])
        left = np.array([-along[1], along[0]])
        length = float(np.linalg.norm(chord))
        lift = -0.001 * (k % 2)
        for inner, outer, texel, name in [
            (-ASPHALT_HALF_WIDTH_M, ASPHALT_HALF_WIDTH_M, road_texel, "asphalt"),
            (-VERGE_OUTER_M, -ASPHALT_HALF_WIDTH_M, verge_texel, "verge right"),
            (ASPHALT_HALF_WIDTH_M, VERGE_OUTER_M, verge_texel, "verge left"),
        ]:
            overlap = max(abs(inner), abs(outer)) * np.tan(max(turn[k], turn[k + 1]) / 2) + 0.05
            size = (length + 2 * overlap, outer - inner)
            origin = start - overlap * along + inner * left
            if name == "asphalt":
                texture = textures.asphalt_texture(size, texel, seed * 7919 + k)
                _paint_markings(texture, size[0] / texture.shape[1], ends[k] - overlap)
                z = lift
            else:
                texture = textures.procedural_texture("rich", size, texel, seed * 7919 + k + (1 if inner > 0 else 2) * 100_000)
                z = lift - 0.004  # below the asphalt where they meet
            quads.append(TexturedQuad([*origin, z], [*along, 0], [*left, 0], size[0], size[1], texture, size[0] / texture.shape[1], f"{name} {k}"))
    return quads


def _building(line, s, side, rng, camera, seed, name) -> list[TexturedQuad]:
    """A front along the road and the end facing oncoming traffic (depth 8-15 m)."""
    front_m, length, depth, height = rng.uniform(12.0, 30.0), rng.uniform(10.0, 30.0), rng.uniform(8.0, 15.0), rng.uniform(6.0, 20.0)
    texel = upright_texel(camera, front_m)
    (corner,), (heading,) = line.at(s, side * front_m)
    along = np.array([np.cos(heading), np.sin(heading)])
    away = side * np.array([-along[1], along[0]])
    front = _vertical_quad(corner, along, length, 0.0, height, textures.facade_texture((length, height), texel, seed), f"{name} front")
    end = _vertical_quad(corner, away, depth, 0.0, height, textures.facade_texture((depth, height), texel, seed + 1), f"{name} end")
    return [front, end]


def _tree(line, s, side, rng, camera, seed, name) -> list[TexturedQuad]:
    """A trunk and a canopy box (3-6 m wide, from 2-3 m up): its road side, near end and underside."""
    lateral, width, bottom, top = rng.uniform(7.0, 9.0), rng.uniform(3.0, 6.0), rng.uniform(2.0, 3.0), rng.uniform(6.0, 10.0)
    (trunk_at,), (heading,) = line.at(s, side * lateral)
    along = np.array([np.cos(heading), np.sin(heading)])
    away = side * np.array([-along[1], along[0]])
    texel = upright_texel(camera, lateral - width / 2)
    leaves = textures.foliage_texture((width, top - bottom), texel, seed)
    bark = textures.foliage_texture((0.4, bottom + 0.5), texel, seed + 1, bark=True)
    corner = trunk_at - width / 2 * (along + away)  # the canopy's corner nearest the road and the oncoming car
    underside = textures.foliage_texture((width, width), texel, seed + 2) // 2
    return [
        _vertical_quad(trunk_at - 0.2 * along, along, 0.4, 0.0, bottom + 0.5, bark, f"{name} trunk"),
        _vertical_quad(corner, along, width, bottom, top - bottom, leaves, f"{name} canopy"),
        _vertical_quad(corner, away, width, bottom, top - bottom, leaves[:, ::-1], f"{name} canopy end"),
        TexturedQuad([*corner, bottom], [*along, 0], [*away, 0], width, width, underside, width / underside.shape[1], f"{name} canopy underside"),
    ]


def _parked_car(line, s, side, rng, camera, seed, name) -> list[TexturedQuad]:
    """A 4.5 x 1.8 x 1.5 m car on the parking strip: its road side and its rear (towards the oncoming car)."""
    lateral = LANE_WIDTH_M + 0.5
    length, width, height = rng.uniform(3.8, 5.0), rng.uniform(1.7, 1.9), rng.uniform(1.4, 1.6)
    (rear,), (heading,) = line.at(s, side * lateral)
    along = np.array([np.cos(heading), np.sin(heading)])
    away = side * np.array([-along[1], along[0]])
    texel = upright_texel(camera, lateral)
    side_texture = textures.vehicle_texture((length, height), texel, seed, side=True)
    rear_texture = textures.vehicle_texture((width, height), texel, seed, side=False)
    return [
        _vertical_quad(rear, along, length, 0.0, height, side_texture, f"{name} side"),
        _vertical_quad(rear, away, width, 0.0, height, rear_texture, f"{name} rear"),
    ]


def roadside(line: Centreline, camera: CameraModel, rng: np.random.Generator, seed: int) -> list[TexturedQuad]:
    """Buildings (blocks of fronts with gaps), trees and runs of parked cars along both sides."""
    quads: list[TexturedQuad] = []
    for side in (-1.0, 1.0):
        s = rng.uniform(0.0, 20.0)
        while s < line.length - 30.0:  # buildings: 60 % of the frontage built, in 10-30 m fronts
            if rng.uniform() < 0.6:
                quads += _building(line, s, side, rng, camera, seed + len(quads), f"building {side:+.0f} {s:.0f}")
            s += rng.uniform(15.0, 40.0)
        s = rng.uniform(0.0, 10.0)
        while s < line.length - 10.0:  # trees every 10-20 m, some missing
            if rng.uniform() < 0.7:
                quads += _tree(line, s, side, rng, camera, seed + len(quads), f"tree {side:+.0f} {s:.0f}")
            s += rng.uniform(10.0, 20.0)
        s = rng.uniform(0.0, 30.0)
        while s < line.length - 10.0:  # runs of 1-5 parked cars, 6 m apart
            for _ in range(int(rng.integers(1, 6))):
                quads += _parked_car(line, s, side, rng, camera, seed + len(quads), f"car {side:+.0f} {s:.0f}")
                s += 6.0
            s += rng.uniform(20.0, 80.0)
    return quads


def far_away(line: Centreline, rng: np.random.Generator, seed: int) -> list[TexturedQuad]:
    """Hills 400-1200 m beyond the route (faces towards it, 150-500 m wide, 20-100 m high) and
    the field under everything, so that part of every view has almost no parallax."""
    centre = line.xy.mean(axis=0)
    reach = np.linalg.norm(line.xy - centre, axis=1).max()
    quads = []
    for k, bearing in enumerate(np.linspace(0.0, 2 * np.pi, 24, endpoint=False) + rng.uniform(0, 0.2)):
        distance = reach + rng.uniform(400.0, 1200.0)
        width, height = rng.uniform(150.0, 500.0), rng.uniform(20.0, 100.0)
        facing = np.array([np.cos(bearing), np.sin(bearing)])
        along = np.array([-facing[1], facing[0]])
        origin = centre + distance * facing - width / 2 * along
        texture = textures.hills_texture((width, height + 10.0), 1.0, seed + k)
        quads.append(_vertical_quad(origin, along, width, -10.0, height + 10.0, texture, f"hill {k}"))
    half = reach + 1300.0
    field = textures.procedural_texture("low", (2 * half, 2 * half), 2 * half / 3000, seed)
    quads.append(TexturedQuad([*(centre - half), -0.02], [1, 0, 0], [0, 1, 0], 2 * half, 2 * half, field, 2 * half / field.shape[1], "field"))
    return quads
