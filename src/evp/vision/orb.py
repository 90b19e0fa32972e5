"""ORB features spread evenly over the image and over the scale pyramid (ORB-SLAM's extractor).

OpenCV's ORB keeps the strongest corners of each level, which piles them onto the most textured
part of the image. Here FAST runs at the *minimum* threshold with FAST scores as responses; each
level's quota is then filled cell by cell (round robin over a grid), preferring corners that pass
the *initial* threshold and falling back to weaker ones only in cells that have none — the
per-cell ini/min threshold rule of ORB-SLAM, done in one detection pass.

Each pyramid level is detected and described by its own single-level OpenCV ORB, so two threads
can share the levels (OpenCV releases the GIL): given a way to run two callables at once (evp.runtime
lends a helper thread), extraction uses both cores of a small machine, with exactly the features
one OpenCV pyramid would give.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable
from dataclasses import dataclass

import cv2
import numpy as np

from evp.config import OrbSettings
from evp.types import CameraModel, LensModel

CELL_PX = 30  # grid cell side on each pyramid level (ORB-SLAM's W)
EDGE_PX = 19  # FAST/ORB border
# Features are kept only where the ray is within this angle of the optical axis. All geometry works
# in undistorted pinhole pixels, where a ray theta off the axis lands at f tan(theta) and a pixel of
# detection noise on a fisheye grows by 1 / cos^2(theta) radially: 8.5 x at 70 degrees, unbounded at
# 90, so such features cost more in outliers than they give. A pinhole sees less than this and
# keeps all its features (measured on the rendered fisheye circle and drone flight: bench/camera_models.py).
MAX_RAY_ANGLE_DEG = 70.0


@dataclass
class Features:
    """Keypoints of one image. ``un_px`` are undistorted pixel coordinates (ideal pinhole, same K),
    the coordinates all geometry uses; ``normalised`` the same on the z = 1 plane.

    ``lens_jacobian`` (None for a lens without distortion: identity) is, per keypoint, the
    derivative of the detected pixel with respect to the undistorted one
    (:meth:`CameraModel.pixel_jacobian`). The detector's noise is isotropic in the detected image,
    so an error e in undistorted pixels weighs as |lens_jacobian @ e|^2 / level sigma^2: a
    fisheye feature 60 degrees off the axis is 4 x noisier radially in undistorted pixels than a
    central one, and every optimiser and gate must know it (docs/decisions.md, "Camera models")."""

    px: np.ndarray  # (N, 2) float, as detected
    un_px: np.ndarray  # (N, 2)
    normalised: np.ndarray  # (N, 2)
    octave: np.ndarray  # (N,) int
    angle: np.ndarray  # (N,) degrees
    descriptors: np.ndarray  # (N, 32) uint8
    lens_jacobian: np.ndarray | None = None  # (N, 2, 2)

    def __len__(self) -> int:
        return len(self.px)

    def subset(self, rows: np.ndarray) -> Features:
        jacobian = None if self.lens_jacobian is None else self.lens_jacobian[rows]
        return Features(self.px[rows], self.un_px[rows], self.normalised[rows], self.octave[rows], self.angle[rows], self.descriptors[rows], jacobian)


def window_stretch(lens_jacobian: np.ndarray | None) -> np.ndarray | float:
    """Per point, how many undistorted pixels one detected pixel spans at most (the inverse of the
    lens Jacobian's smaller singular value; 1.0 without one): a search window or band of r detected
    pixels, the detector's scale, needs r times this in the undistorted pixels matching works in.
    On a fisheye 60 degrees off the axis, 4."""
    if lens_jacobian is None:
        return 1.0
    return 1.0 / np.linalg.svd(lens_jacobian, compute_uv=False)[:, -1]


def usable_levels(settings: OrbSettings, camera: CameraModel) -> int:
    """Pyramid levels to use: at most ``settings.pyramid_levels``, and only levels whose shorter
    side still holds one grid cell inside the FAST/ORB borders. On a small sensor (240x180) the
    coarsest of 8 levels is a few pixels of usable image; its quota goes to finer levels instead."""
    short_side = min(camera.width, camera.height)
    fitting = int(np.floor(np.log(short_side / (2 * EDGE_PX + CELL_PX)) / np.log(settings.scale_factor))) + 1
    return int(np.clip(fitting, 1, settings.pyramid_levels))


def _per_level(total: int, scale_factor: float, levels: int) -> np.ndarray:
    """``total`` shared over the levels geometrically in the level's size, the rest to the last:
    ORB-SLAM's features per level, and how many corners OpenCV's ORB keeps per level."""
    ratio = 1.0 / scale_factor
    desired = total * (1 - ratio) / (1 - ratio**levels)
    share = np.zeros(levels, int)
    for level in range(levels - 1):
        share[level] = round(desired)
        desired *= ratio
    share[-1] = max(total - share[:-1].sum(), 0)
    return share


def _cone_masks(camera: CameraModel, scale_factors: np.ndarray) -> list[np.ndarray | None]:
    """Per pyramid level, the detection mask of the pixels whose ray is within
    ``MAX_RAY_ANGLE_DEG`` of the optical axis; None on every level when the whole image is (the
    border holds the rays furthest off the axis)."""
    min_cos = np.cos(np.radians(MAX_RAY_ANGLE_DEG))
    if not np.any(camera.bearings(camera.border_pixels(101))[:, 2] < min_cos):
        return [None] * len(scale_factors)
    u, v = np.meshgrid(np.arange(camera.width, dtype=float), np.arange(camera.height, dtype=float))
    inside = ~(camera.bearings(np.column_stack([u.ravel(), v.ravel()]))[:, 2] < min_cos)
    mask = inside.reshape(camera.height, camera.width).astype(np.uint8) * 255
    sizes = [(round(camera.width / s), round(camera.height / s)) for s in scale_factors]  # as the pyramid's
    return [cv2.resize(mask, size, interpolation=cv2.INTER_NEAREST) for size in sizes]


class OrbExtractor:
    """``parallel`` runs the callables it is given at once and returns their results: two share the
    levels. None: every level in the caller's thread (same features)."""

    def __init__(self, settings: OrbSettings, camera: CameraModel, parallel: Callable[..., list] | None = None):
        self.settings = settings
        self.camera = camera
        levels = usable_levels(settings, camera)
        self.scale_factors = settings.scale_factor ** np.arange(levels)
        self.level_sigma2 = self.scale_factors**2
        self.inv_level_sigma2 = 1.0 / self.level_sigma2
        # features per level, geometric in the level's size (ORB-SLAM's rule, also OpenCV's)
        self.level_quota = _per_level(settings.n_features, settings.scale_factor, levels)
        # one single-level OpenCV ORB per level, on our copy of its pyramid (built as OpenCV
        # builds it), keeping as many corners per level as one 3 x n_features ORB would
        retained = _per_level(3 * settings.n_features, settings.scale_factor, levels)
        self._level_detectors = [
            cv2.ORB_create(
                nfeatures=int(n),
                nlevels=1,
                edgeThreshold=EDGE_PX,
                firstLevel=0,
                WTA_K=2,
                scoreType=cv2.ORB_FAST_SCORE,
                patchSize=31,
                fastThreshold=settings.min_fast_threshold,
            )
            for n in retained
        ]
        self._parallel = parallel if levels > 1 else None
        self._level_masks = _cone_masks(camera, self.scale_factors)
        # Search windows are widened by the lens (``window_stretch``) on a fisheye only: there they
        # reach 4 x at 60 degrees, while a radtan lens's reach 1.16 at most (the phone preset's corners), and that
        # widening only let in look-alikes (rendered circle seed 2: 0.0103 -> 0.0118 m, decisions.md).
        self.widens_windows = camera.lens is LensModel.EQUIDISTANT

    def extract(self, grey: np.ndarray, budget: int = 1) -> Features:
        """``budget`` times the configured features (1 to 3: the detectors keep 3 times the quota).

        In parallel, one task extracts level 0 at once while the other builds the rest of the
        pyramid, queueing each level as it is built; then both take the next level queued, largest
        first, until none is (the per-level cost is not proportional to the area, so a fixed split
        left one thread waiting 4 ms on MH01). Which task takes which level changes nothing found."""
        pyramid: list[np.ndarray | None] = [grey] + [None] * (len(self.scale_factors) - 1)
        found: dict[int, tuple[np.ndarray, ...] | None] = {}
        if self._parallel is None:
            waiting = deque([0])
            self._build_pyramid(pyramid, waiting)
            self._extract_queued(waiting, pyramid, found, budget)
        else:
            waiting = deque()

            def build_then_extract() -> None:
                self._build_pyramid(pyramid, waiting)
                self._extract_queued(waiting, pyramid, found, budget)

            def first_level_then_extract() -> None:
                found[0] = self._extract_level(0, grey, budget)
                self._extract_queued(waiting, pyramid, found, budget)

            self._parallel(build_then_extract, first_level_then_extract)
        parts = [found[level] for level in sorted(found) if found[level] is not None]
        if not parts:
            return self._empty()
        px = np.vstack([part[0] for part in parts])
        normalised = self.camera.undistort_points(px)
        un_px = normalised * [self.camera.fx, self.camera.fy] + [self.camera.cx, self.camera.cy]
        jacobian = self.lens_jacobian(normalised)
        return Features(px, un_px, normalised, *(np.concatenate([part[k] for part in parts]) for k in (1, 2)), np.vstack([part[3] for part in parts]), jacobian)

    def window_stretch(self, lens_jacobian: np.ndarray | None) -> np.ndarray | float:
        """:func:`window_stretch` where this lens widens search windows, else 1.0."""
        return window_stretch(lens_jacobian) if self.widens_windows else 1.0

    def lens_jacobian(self, normalised: np.ndarray) -> np.ndarray | None:
        """The lens Jacobians (``Features.lens_jacobian``) at (N, 2) normalised undistorted
        coordinates; None for a lens without distortion."""
        return self.camera.pixel_jacobian(normalised) if self.camera.has_distortion else None

    def _build_pyramid(self, pyramid: list[np.ndarray | None], built: deque) -> None:
        """Each level resized from the one before, as OpenCV builds its pyramid; its index is
        queued on ``built`` once it is there (a deque's append is atomic)."""
        height, width = pyramid[0].shape
        for level in range(1, len(pyramid)):
            size = (round(width / self.scale_factors[level]), round(height / self.scale_factors[level]))
            pyramid[level] = cv2.resize(pyramid[level - 1], size, interpolation=cv2.INTER_LINEAR_EXACT)
            built.append(level)

    def _extract_queued(self, waiting: deque, pyramid: list, found: dict, budget: int) -> None:
        """Take levels from ``waiting`` (a deque's popleft is atomic) until it is empty."""
        while True:
            try:
                level = waiting.popleft()
            except IndexError:
                return
            found[level] = self._extract_level(level, pyramid[level], budget)

    def _extract_level(self, level: int, image: np.ndarray, budget: int = 1) -> tuple[np.ndarray, ...] | None:
        detector = self._level_detectors[level]
        keypoints = detector.detect(image, self._level_masks[level])
        if not keypoints:
            return None
        scale = np.float32(self.scale_factors[level])  # float32 products, as OpenCV scales its keypoints
        response = np.fromiter((k.response for k in keypoints), float, len(keypoints))
        chosen = self._distribute(cv2.KeyPoint_convert(keypoints) * scale, np.full(len(keypoints), level), response, budget)
        keypoints, descriptors = detector.compute(image, [keypoints[i] for i in chosen])
        if descriptors is None or not keypoints:
            return None
        return (
            (cv2.KeyPoint_convert(keypoints) * scale).astype(float),
            np.full(len(keypoints), level),
            np.fromiter((k.angle for k in keypoints), float, len(keypoints)),
            descriptors,
        )

    def _distribute(self, xy: np.ndarray, octave: np.ndarray, response: np.ndarray, budget: int = 1) -> np.ndarray:
        """Indices of the kept keypoints, level by level: round robin over grid cells, strongest
        first in each cell, until the level's quota is filled."""
        strong = response >= self.settings.ini_fast_threshold
        cell = CELL_PX * self.scale_factors[octave]
        cell_id = (octave.astype(np.int64) * 10000 + (xy[:, 1] // cell).astype(np.int64)) * 10000 + (xy[:, 0] // cell).astype(np.int64)
        usable = strong | ~np.isin(cell_id, cell_id[strong])  # weak corners only where the cell has no strong one
        rows = np.flatnonzero(usable)
        cell_id, response, octave = cell_id[rows], response[rows], octave[rows]
        order = np.lexsort((-response, cell_id))  # by level and cell, strongest first
        sorted_cells = cell_id[order]
        starts = np.r_[0, np.flatnonzero(np.diff(sorted_cells)) + 1]
        rank = np.arange(len(order)) - np.repeat(starts, np.diff(np.r_[starts, len(order)]))
        order = order[np.lexsort((-response[order], rank, octave[order]))]  # by level, round, strength
        level = octave[order]
        level_start = np.searchsorted(level, level)
        keep = np.arange(len(order)) - level_start < budget * self.level_quota[np.clip(level, 0, len(self.level_quota) - 1)]
        return rows[order[keep]]

    @staticmethod
    def _empty() -> Features:
        z2 = np.zeros((0, 2))
        return Features(z2, z2, z2, np.zeros(0, int), np.zeros(0), np.zeros((0, 32), np.uint8))
