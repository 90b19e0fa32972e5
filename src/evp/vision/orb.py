"""ORB features spread evenly over the image and over the scale pyramid (ORB-SLAM's extractor).

OpenCV's ORB keeps the strongest corners of each level, which piles them onto the most textured
part of the image. Here FAST runs at the *minimum* threshold with FAST scores as responses; each
level's quota is then filled cell by cell (round robin over a grid), preferring corners that pass
the *initial* threshold and falling back to weaker ones only in cells that have none — the
per-cell ini/min threshold rule of ORB-SLAM, done in one detection pass.

Each pyramid level is detected and described by its own single-level OpenCV ORB, so the levels
can be split into two groups of about equal area, the coarse one in a second thread (OpenCV
releases the GIL): extraction uses both cores of a small machine, with exactly the features one
OpenCV pyramid would give.
"""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import cv2
import numpy as np

from evp.config import OrbSettings
from evp.types import CameraModel

CELL_PX = 30  # grid cell side on each pyramid level (ORB-SLAM's W)
EDGE_PX = 19  # FAST/ORB border


@dataclass
class Features:
    """Keypoints of one image. ``un_px`` are undistorted pixel coordinates (ideal pinhole, same K),
    the coordinates all geometry uses; ``normalised`` the same on the z = 1 plane."""

    px: np.ndarray  # (N, 2) float, as detected
    un_px: np.ndarray  # (N, 2)
    normalised: np.ndarray  # (N, 2)
    octave: np.ndarray  # (N,) int
    angle: np.ndarray  # (N,) degrees
    descriptors: np.ndarray  # (N, 32) uint8

    def __len__(self) -> int:
        return len(self.px)

    def subset(self, rows: np.ndarray) -> Features:
        return Features(self.px[rows], self.un_px[rows], self.normalised[rows], self.octave[rows], self.angle[rows], self.descriptors[rows])


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


def _split_levels(scale_factors: np.ndarray) -> list[list[int]]:
    """Levels in two groups of about equal area, fine [0, k) and coarse [k, L) (one if L = 1)."""
    area = np.cumsum(scale_factors**-2.0)
    split = int(np.searchsorted(area, area[-1] / 2)) + 1
    levels = list(range(len(scale_factors)))
    return [levels[:split], levels[split:]] if split < len(levels) else [levels]


class OrbExtractor:
    """``parallel``: the coarse levels in a second thread (the default); off, every level in the
    caller's thread (same features)."""

    def __init__(self, settings: OrbSettings, camera: CameraModel, parallel: bool = True):
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
        self._level_groups = _split_levels(self.scale_factors) if parallel else [list(range(levels))]
        self._helper = ThreadPoolExecutor(1, thread_name_prefix="orb") if len(self._level_groups) > 1 else None

    def extract(self, grey: np.ndarray) -> Features:
        coarse = [self._helper.submit(self._extract_levels, levels, grey) for levels in self._level_groups[1:]]
        parts = self._extract_levels(self._level_groups[0], grey) + [part for job in coarse for part in job.result()]
        if not parts:
            return self._empty()
        px = np.vstack([part[0] for part in parts])
        normalised = self.camera.undistort_points(px)
        un_px = normalised * [self.camera.fx, self.camera.fy] + [self.camera.cx, self.camera.cy]
        return Features(px, un_px, normalised, *(np.concatenate([part[k] for part in parts]) for k in (1, 2)), np.vstack([part[3] for part in parts]))

    def _extract_levels(self, levels: list[int], grey: np.ndarray) -> list[tuple[np.ndarray, ...]]:
        """(px at level 0, octave, angle, descriptors) of the kept features of each level.

        Positions are level pixels times scale_factor^level, OpenCV's (and ORB-SLAM's) convention."""
        parts = []
        height, width = grey.shape
        image = grey
        for level in range(levels[-1] + 1):
            if level > 0:  # each level resized from the one before, as OpenCV builds its pyramid
                size = (round(width / self.scale_factors[level]), round(height / self.scale_factors[level]))
                image = cv2.resize(image, size, interpolation=cv2.INTER_LINEAR_EXACT)
            if level in levels:
                part = self._extract_level(level, image)
                if part is not None:
                    parts.append(part)
        return parts

    def _extract_level(self, level: int, image: np.ndarray) -> tuple[np.ndarray, ...] | None:
        detector = self._level_detectors[level]
        keypoints = detector.detect(image)
        if not keypoints:
            return None
        scale = np.float32(self.scale_factors[level])  # float32 products, as OpenCV scales its keypoints
        response = np.fromiter((k.response for k in keypoints), float, len(keypoints))
        chosen = self._distribute(cv2.KeyPoint_convert(keypoints) * scale, np.full(len(keypoints), level), response)
        keypoints, descriptors = detector.compute(image, [keypoints[i] for i in chosen])
        if descriptors is None or not keypoints:
            return None
        return (
            (cv2.KeyPoint_convert(keypoints) * scale).astype(float),
            np.full(len(keypoints), level),
            np.fromiter((k.angle for k in keypoints), float, len(keypoints)),
            descriptors,
        )

    def _distribute(self, xy: np.ndarray, octave: np.ndarray, response: np.ndarray) -> np.ndarray:
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
        keep = np.arange(len(order)) - level_start < self.level_quota[np.clip(level, 0, len(self.level_quota) - 1)]
        return rows[order[keep]]

    @staticmethod
    def _empty() -> Features:
        z2 = np.zeros((0, 2))
        return Features(z2, z2, z2, np.zeros(0, int), np.zeros(0), np.zeros((0, 32), np.uint8))
