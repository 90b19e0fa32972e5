"""Ground, floor and wall textures: procedural (seeded), from image files, and ArUco marker fields.

All textures are grey uint8 with a stated size in metres per texel. The procedural ones are sums
of smooth random fields at several scales plus kind-specific structure, so the amount of trackable
detail differs as it does outdoors: a paved square (rich) against a mown grass field (low).
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from evp.errors import DataFormatError, UsageError

TEXTURE_KINDS = ("rich", "low", "pitch", "floor", "wall")
MAX_TEXELS = 12000  # per side; coarser texels are used beyond this


def _smooth_noise(rng: np.random.Generator, shape: tuple[int, int], cell_px: float) -> np.ndarray:
    """Zero-mean, unit-range random field with features about ``cell_px`` texels wide."""
    coarse = (max(2, int(shape[0] / cell_px) + 2), max(2, int(shape[1] / cell_px) + 2))
    field = rng.uniform(-1.0, 1.0, coarse).astype(np.float32)
    return cv2.resize(field, (shape[1], shape[0]), interpolation=cv2.INTER_CUBIC)


def _octaves(rng, shape, metres_per_texel: float, scales_m: list[float], weights: list[float]) -> np.ndarray:
    out = np.zeros(shape, np.float32)
    for scale, weight in zip(scales_m, weights):
        out += weight * _smooth_noise(rng, shape, max(1.5, scale / metres_per_texel))
    return out


def procedural_texture(kind: str, size_m: tuple[float, float], metres_per_texel: float, seed: int = 0) -> np.ndarray:
    """A seeded texture of ``size_m`` (width, height) metres.

    rich: paved square (slabs, joints, stains, small objects); low: grass field (faint mottling and
    a few painted lines); pitch: a mown football pitch seen from a drone's height (mowing stripes,
    grass clumps, worn patches, the pitch's lines); floor: indoor tiles; wall: painted plaster with
    posters and doors.
    """
    if kind not in TEXTURE_KINDS:
        raise UsageError(f"unknown texture {kind!r}; choose one of {', '.join(TEXTURE_KINDS)} or an image file")
    rng = np.random.default_rng(seed)
    shape = (max(8, int(round(size_m[1] / metres_per_texel))), max(8, int(round(size_m[0] / metres_per_texel))))
    if kind == "rich":
        base = 128 + _octaves(rng, shape, metres_per_texel, [20.0, 4.0, 0.8, 0.25], [35, 30, 25, 15])
        slab = max(2, int(round(1.2 / metres_per_texel)))
        joints = (np.arange(shape[0])[:, None] % slab < max(1, slab // 12)) | (np.arange(shape[1])[None, :] % slab < max(1, slab // 12))
        base[joints] -= 45
        for _ in range(int(shape[0] * shape[1] * metres_per_texel**2 / 40) + 5):  # benches, bins, cars, shadows
            centre = (int(rng.integers(0, shape[1])), int(rng.integers(0, shape[0])))
            axes = (int(rng.uniform(0.3, 2.5) / metres_per_texel) + 1, int(rng.uniform(0.3, 1.5) / metres_per_texel) + 1)
            cv2.ellipse(base, centre, axes, float(rng.uniform(0, 180)), 0, 360, float(rng.uniform(20, 235)), -1)
    elif kind == "low":
        base = 110 + _octaves(rng, shape, metres_per_texel, [15.0, 3.0, 0.5], [10, 5, 3])
        for _ in range(3):  # painted lines of a pitch
            if rng.uniform() < 0.5:
                x = int(rng.integers(0, shape[1]))
                base[:, x : x + max(1, int(0.12 / metres_per_texel))] = 220
            else:
                y = int(rng.integers(0, shape[0]))
                base[y : y + max(1, int(0.12 / metres_per_texel)), :] = 220
    elif kind == "pitch":
        base = _pitch(rng, shape, metres_per_texel)
    elif kind == "floor":
        base = 150 + _octaves(rng, shape, metres_per_texel, [2.0, 0.3, 0.05], [15, 20, 25])
        tile = max(2, int(round(0.4 / metres_per_texel)))
        grout = (np.arange(shape[0])[:, None] % tile < max(1, tile // 20)) | (np.arange(shape[1])[None, :] % tile < max(1, tile // 20))
        base[grout] -= 60
        for _ in range(int(shape[0] * shape[1] * metres_per_texel**2 * 2) + 5):  # scuffs, stains
            centre = (int(rng.integers(0, shape[1])), int(rng.integers(0, shape[0])))
            radius = int(rng.uniform(0.01, 0.08) / metres_per_texel) + 1
            cv2.circle(base, centre, radius, float(rng.uniform(40, 230)), -1)
    else:
        base = 170 + _octaves(rng, shape, metres_per_texel, [3.0, 0.5, 0.05], [12, 10, 8])
        for _ in range(int(shape[0] * shape[1] * metres_per_texel**2 / 1.5) + 3):  # posters, doors, shelves
            x0, y0 = int(rng.integers(0, shape[1])), int(rng.integers(0, shape[0]))
            w, h = int(rng.uniform(0.2, 1.0) / metres_per_texel), int(rng.uniform(0.2, 1.2) / metres_per_texel)
            patch = rng.uniform(30, 230) + 40 * _smooth_noise(rng, (max(2, h), max(2, w)), max(1.5, 0.05 / metres_per_texel))
            base[y0 : y0 + h, x0 : x0 + w] = patch[: shape[0] - y0, : shape[1] - x0]
    return np.clip(base, 0, 255).astype(np.uint8)


# A mown pitch from 10-20 m up (2-3 cm a pixel): the mower's stripes (5 m wide, a few grey levels
# apart), grass clumps and tufts at 5-30 cm with the contrast of blades in their own shadow, worn
# patches of bare soil (goalmouths, the centre spot), and white lines 12 cm wide. Photographs of
# pitches from drones at that height show all four; "low" (faint metre-scale mottling only) has
# none of the clumps a feature detector finds on real grass, so no visual odometry could track it.
PITCH_STRIPE_M = 5.0
PITCH_GRASS_SCALES_M = [12.0, 2.0, 0.3, 0.08]
PITCH_GRASS_WEIGHTS = [8, 6, 9, 12]


def _pitch(rng: np.random.Generator, shape: tuple[int, int], metres_per_texel: float) -> np.ndarray:
    base = 100 + _octaves(rng, shape, metres_per_texel, PITCH_GRASS_SCALES_M, PITCH_GRASS_WEIGHTS)
    stripe = (np.arange(shape[1]) * metres_per_texel // PITCH_STRIPE_M) % 2
    base += np.where(stripe == 0, 6.0, -6.0)[None, :]
    soften = max(1.0, 0.3 / metres_per_texel)
    for _ in range(int(shape[0] * shape[1] * metres_per_texel**2 / 120) + 2):  # worn, bare patches
        half = int(3.0 / metres_per_texel + 3 * soften) + 1
        x, y = int(rng.integers(0, shape[1])), int(rng.integers(0, shape[0]))
        window = (slice(max(0, y - half), y + half), slice(max(0, x - half), x + half))
        local = base[window]
        wear = np.zeros(local.shape, np.float32)
        axes = (int(rng.uniform(0.5, 3.0) / metres_per_texel) + 1, int(rng.uniform(0.4, 2.0) / metres_per_texel) + 1)
        cv2.ellipse(wear, (x - window[1].start, y - window[0].start), axes, float(rng.uniform(0, 180)), 0, 360, 1.0, -1)
        local += 25 * cv2.GaussianBlur(wear, (0, 0), soften) * (0.6 + 0.4 * _smooth_noise(rng, local.shape, max(1.5, 0.2 / metres_per_texel)))
    line = max(1, int(round(0.12 / metres_per_texel)))
    for x in (shape[1] // 8, shape[1] // 2, shape[1] - shape[1] // 8):  # touchline, halfway line, touchline
        base[:, x : x + line] = 215
    centre = (shape[1] // 2, shape[0] // 2)
    cv2.circle(base, centre, int(9.15 / metres_per_texel), 215.0, line)
    return base


def image_texture(paths: list[Path], tiles_x: int | None = None) -> np.ndarray:
    """Grey mosaic of image files, side by side in rows (a larger field from several nadir photos)."""
    images = []
    for path in paths:
        image = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
        if image is None:
            raise DataFormatError(path, "cannot read texture image")
        images.append(image)
    height, width = images[0].shape
    images = [cv2.resize(i, (width, height), interpolation=cv2.INTER_AREA) for i in images]
    cols = tiles_x or int(np.ceil(np.sqrt(len(images))))
    rows = int(np.ceil(len(images) / cols))
    mosaic = np.zeros((rows * height, cols * width), np.uint8)
    for k, image in enumerate(images):
        r, c = divmod(k, cols)
        mosaic[r * height : (r + 1) * height, c * width : (c + 1) * width] = image
    return mosaic


# seed 003: 99 markers of 98 mm with 98 mm gaps (9 x 11), 1.86 x 2.25 m with the border gap
MARKER_SIZE_M = 0.098
MARKER_GAP_M = 0.098
MARKER_COLS = 9
MARKER_ROWS = 11
MARKER_DICTIONARY = "DICT_4X4_100"


def marker_field_texture(texels_per_marker: int = 36) -> tuple[np.ndarray, float, dict[int, np.ndarray]]:
    """ArUco marker floor: (texture, metres per texel, marker id -> centre (x, y) in metres from
    the field's corner). Marker ``id = row * 9 + col``; rows run along +y.

    Texture rows run along the floor's +y, which a camera looking down sees as image up, so each
    marker is drawn upside down in the texture: seen from above it reads as itself (drawn as it
    comes it is mirrored, and a mirrored marker decodes as nothing or as another id). Its top edge
    points along +y. 36 texels (6 per code cell) keep the cell edges sharp down to a 0.15 m
    landing view."""
    mpt = MARKER_SIZE_M / texels_per_marker
    gap = int(round(MARKER_GAP_M / mpt))
    width = MARKER_COLS * texels_per_marker + (MARKER_COLS + 1) * gap
    height = MARKER_ROWS * texels_per_marker + (MARKER_ROWS + 1) * gap
    texture = np.full((height, width), 255, np.uint8)
    dictionary = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, MARKER_DICTIONARY))
    centres = {}
    for row in range(MARKER_ROWS):
        for col in range(MARKER_COLS):
            marker_id = row * MARKER_COLS + col
            x0 = gap + col * (texels_per_marker + gap)
            y0 = gap + row * (texels_per_marker + gap)
            texture[y0 : y0 + texels_per_marker, x0 : x0 + texels_per_marker] = cv2.aruco.generateImageMarker(dictionary, marker_id, texels_per_marker)[::-1]
            centres[marker_id] = np.array([(x0 + texels_per_marker / 2) * mpt, (y0 + texels_per_marker / 2) * mpt])
    return texture, mpt, centres


# --- what lines a road: asphalt, facades, parked cars, foliage, bark and distant hills ---------------------
# Upright surfaces are drawn as images (row 0 at the top); the road module flips them onto quads whose
# v axis points up.


def _shape(size_m: tuple[float, float], metres_per_texel: float) -> tuple[int, int]:
    return max(8, int(round(size_m[1] / metres_per_texel))), max(8, int(round(size_m[0] / metres_per_texel)))


def asphalt_texture(size_m: tuple[float, float], metres_per_texel: float, seed: int) -> np.ndarray:
    """Dark asphalt: grain at the texel scale, mottling, tar patches and cracks (no markings)."""
    rng = np.random.default_rng(seed)
    shape = _shape(size_m, metres_per_texel)
    base = 85 + _octaves(rng, shape, metres_per_texel, [6.0, 1.0, 0.2], [12, 10, 8]) + rng.uniform(-12, 12, shape).astype(np.float32)
    for _ in range(int(size_m[0] * size_m[1] / 25) + 1):  # tar patches and oil stains
        centre = (int(rng.integers(0, shape[1])), int(rng.integers(0, shape[0])))
        axes = (int(rng.uniform(0.2, 1.5) / metres_per_texel) + 1, int(rng.uniform(0.1, 0.8) / metres_per_texel) + 1)
        cv2.ellipse(base, centre, axes, float(rng.uniform(0, 180)), 0, 360, float(rng.uniform(45, 75)), -1)
    for _ in range(int(size_m[0] * size_m[1] / 40) + 1):  # sealed cracks
        points = np.cumsum(rng.normal(0, 0.3 / metres_per_texel, (6, 2)), axis=0) + [rng.integers(0, shape[1]), rng.integers(0, shape[0])]
        cv2.polylines(base, [points.astype(np.int32)], False, float(rng.uniform(40, 60)), max(1, int(0.02 / metres_per_texel)))
    return np.clip(base, 0, 255).astype(np.uint8)


def facade_texture(size_m: tuple[float, float], metres_per_texel: float, seed: int) -> np.ndarray:
    """A building front: plaster, a shop or door band on the ground floor, then floors of windows
    (3.2 m apart) each with its own pane brightness and curtain."""
    rng = np.random.default_rng(seed)
    shape = _shape(size_m, metres_per_texel)
    base = rng.uniform(120, 200) + _octaves(rng, shape, metres_per_texel, [8.0, 1.0, 0.1], [10, 6, 6])
    px = 1.0 / metres_per_texel
    floor_m, bay_m = 3.2, rng.uniform(2.4, 3.6)
    window_w, window_h = rng.uniform(0.9, 1.5), rng.uniform(1.2, 1.7)
    for k in range(int(size_m[1] / floor_m)):  # rows count from the bottom of the facade
        bottom = shape[0] - int(k * floor_m * px)
        if k == 0:  # shop windows and doors
            for x in np.arange(rng.uniform(0.3, 1.5), size_m[0] - 1.0, rng.uniform(3.0, 6.0)):
                w = rng.uniform(1.0, 3.0)
                top = bottom - int(rng.uniform(2.0, 2.6) * px)
                base[top : bottom - int(0.1 * px), int(x * px) : int((x + w) * px)] = rng.uniform(20, 110)
            continue
        sill = bottom - int(0.9 * px)
        for x in np.arange(bay_m / 2 - window_w / 2, size_m[0] - window_w, bay_m):
            c0, c1, r0 = int(x * px), int((x + window_w) * px), sill - int(window_h * px)
            base[r0 - 2 : sill + 2, c0 - 2 : c1 + 2] = 235  # frame
            base[r0:sill, c0:c1] = rng.uniform(25, 120)  # pane
            if rng.uniform() < 0.5:  # a curtain on one side
                split = c0 + int(rng.uniform(0.2, 0.6) * (c1 - c0))
                base[r0:sill, c0:split] = rng.uniform(140, 220)
    return np.clip(base, 0, 255).astype(np.uint8)


def vehicle_texture(size_m: tuple[float, float], metres_per_texel: float, seed: int, side: bool) -> np.ndarray:
    """A parked car seen from the side (``side``: wheels and two windows) or from behind (rear
    window, lights and number plate); the body a random paint shade."""
    rng = np.random.default_rng(seed)
    shape = _shape(size_m, metres_per_texel)
    base = np.full(shape, rng.uniform(40, 220), np.float32) + _octaves(rng, shape, metres_per_texel, [1.0, 0.1], [6, 4])
    height, width = shape
    base[int(0.1 * height) : int(0.42 * height), int(0.12 * width) : int(0.88 * width)] = rng.uniform(20, 60)  # glass
    if side:
        base[int(0.1 * height) : int(0.42 * height), int(0.49 * width) : int(0.52 * width)] = 30  # door pillar
        for centre in (0.18, 0.8):
            cv2.circle(base, (int(centre * width), int(0.82 * height)), int(0.2 * height), 15, -1)
            cv2.circle(base, (int(centre * width), int(0.82 * height)), int(0.1 * height), 150, -1)
    else:
        for left in (0.05, 0.8):
            base[int(0.5 * height) : int(0.62 * height), int(left * width) : int((left + 0.15) * width)] = 70  # lights
        base[int(0.62 * height) : int(0.72 * height), int(0.38 * width) : int(0.62 * width)] = 240  # plate
        base[int(0.85 * height) :] = 20  # bumper shadow
    return np.clip(base, 0, 255).astype(np.uint8)


def foliage_texture(size_m: tuple[float, float], metres_per_texel: float, seed: int, bark: bool = False) -> np.ndarray:
    """Leaves (blotches of light and shade from 5 cm to 1 m) or, with ``bark``, a dark trunk with
    vertical furrows."""
    rng = np.random.default_rng(seed)
    shape = _shape(size_m, metres_per_texel)
    if bark:
        furrows = _smooth_noise(rng, (max(2, shape[0] // 8), shape[1]), max(1.5, 0.05 / metres_per_texel))
        return np.clip(60 + 25 * cv2.resize(furrows, (shape[1], shape[0]), interpolation=cv2.INTER_LINEAR), 0, 255).astype(np.uint8)
    return np.clip(95 + _octaves(rng, shape, metres_per_texel, [1.0, 0.3, 0.08], [30, 30, 25]), 0, 255).astype(np.uint8)


def hills_texture(size_m: tuple[float, float], metres_per_texel: float, seed: int) -> np.ndarray:
    """Distant wooded hills and town: large soft shapes, darker towards the foot."""
    rng = np.random.default_rng(seed)
    shape = _shape(size_m, metres_per_texel)
    base = 120 + _octaves(rng, shape, metres_per_texel, [60.0, 15.0, 4.0], [30, 25, 20]) - np.linspace(0, 30, shape[0], dtype=np.float32)[::-1, None]
    return np.clip(base, 0, 255).astype(np.uint8)
