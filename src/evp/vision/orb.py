"""ORB features spread evenly over the image and over the scale pyramid (ORB-SLAM's extractor).

OpenCV's ORB keeps the strongest corners of each level, which piles them onto the most textured
part of the image. Here FAST runs at the *minimum* threshold with FAST scores as responses; each
level's quota is then filled cell by cell (round robin over a grid), preferring corners that pass
the *initial* threshold and falling back to weaker ones only in cells that have none — the
per-cell ini/min threshold rule of ORB-SLAM, done in one detection pass.
"""

from __future__ import annotations

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


class OrbExtractor:
    def __init__(self, settings: OrbSettings, camera: CameraModel):
        self.settings = settings
        self.camera = camera
        levels = usable_levels(settings, camera)
        self.scale_factors = settings.scale_factor ** np.arange(levels)
        self.level_sigma2 = self.scale_factors**2
        self.inv_level_sigma2 = 1.0 / self.level_sigma2
        # features per level, geometric in the level's area (ORB-SLAM)
        ratio = 1.0 / settings.scale_factor
        first = settings.n_features * (1 - ratio) / (1 - ratio**levels)
        quota = np.round(first * ratio ** np.arange(levels)).astype(int)
        quota[-1] = max(0, settings.n_features - quota[:-1].sum())
        self.level_quota = quota
        self._detector = cv2.ORB_create(
            nfeatures=3 * settings.n_features,
            scaleFactor=settings.scale_factor,
            nlevels=levels,
            edgeThreshold=EDGE_PX,
            firstLevel=0,
            WTA_K=2,
            scoreType=cv2.ORB_FAST_SCORE,
            patchSize=31,
            fastThreshold=settings.min_fast_threshold,
        )

    def extract(self, grey: np.ndarray) -> Features:
        keypoints = self._detector.detect(grey)
        if not keypoints:
            return self._empty()
        xy = cv2.KeyPoint_convert(keypoints).astype(float)
        octave = np.fromiter((k.octave for k in keypoints), int, len(keypoints))
        response = np.fromiter((k.response for k in keypoints), float, len(keypoints))
        chosen = self._distribute(xy, octave, response)
        keypoints, descriptors = self._detector.compute(grey, [keypoints[i] for i in chosen])
        if descriptors is None or not keypoints:
            return self._empty()
        px = cv2.KeyPoint_convert(keypoints).astype(float)
        normalised = self.camera.undistort_points(px)
        un_px = normalised * [self.camera.fx, self.camera.fy] + [self.camera.cx, self.camera.cy]
        return Features(
            px,
            un_px,
            normalised,
            np.fromiter((k.octave for k in keypoints), int, len(keypoints)),
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
