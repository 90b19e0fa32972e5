"""Finding the map's features in an image: FAST corners, searched for each feature only inside
the region its predicted measurement's uncertainty allows (active search, as MonoSLAM; seed 001's
future work asks for this filter), matched by ORB descriptor; and picking corners for new features."""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import cv2
import numpy as np

from evp.ekf_slam.filter import chi2_quantile
from evp.types import CameraModel

POPCOUNT = np.array([bin(v).count("1") for v in range(256)], dtype=np.uint8)
ORB_PATCH_BORDER_PX = 16  # OpenCV's ORB drops keypoints whose 31-pixel patch leaves the image


@dataclass(frozen=True)
class Corners:
    """FAST corners of one image: ``pixels`` (N, 2), ``normalised`` (N, 2) undistorted
    coordinates and the OpenCV keypoints to describe them from; ``responses`` (N,), the corner
    scores, are read only when new features are picked."""

    pixels: np.ndarray
    normalised: np.ndarray
    keypoints: tuple

    @cached_property
    def responses(self) -> np.ndarray:
        return np.array([k.response for k in self.keypoints], dtype=float)


class PixelRays:
    """The undistorted normalised coordinates of every whole pixel of a camera's image, computed
    once: FAST corners lie on whole pixels, so a frame's corners are looked up instead of each
    inverted through the lens model by Newton's method (2 ms of a frame's ~1700 corners at
    640x380; the table is the same inversion, 0.2 s once, 4 MB)."""

    def __init__(self, camera: CameraModel):
        self.camera = camera
        u, v = np.meshgrid(np.arange(camera.width, dtype=float), np.arange(camera.height, dtype=float))
        self._table = camera.undistort_points(np.column_stack([u.ravel(), v.ravel()]))  # row by row

    def normalised(self, pixels: np.ndarray) -> np.ndarray:
        """(N, 2) normalised coordinates of (N, 2) pixels (off the whole pixels of the image: the
        lens model's own inversion)."""
        if len(pixels) == 0:
            return np.zeros((0, 2))
        columns, rows = pixels[:, 0].astype(int), pixels[:, 1].astype(int)
        whole = np.array_equal(columns, pixels[:, 0]) and np.array_equal(rows, pixels[:, 1])
        if whole and columns.min() >= 0 and rows.min() >= 0 and columns.max() < self.camera.width and rows.max() < self.camera.height:
            return self._table[rows * self.camera.width + columns]
        return self.camera.undistort_points(pixels)


def detect_corners(grey: np.ndarray, rays: PixelRays, threshold: int) -> Corners:
    mask = np.zeros(grey.shape, dtype=np.uint8)
    mask[ORB_PATCH_BORDER_PX:-ORB_PATCH_BORDER_PX, ORB_PATCH_BORDER_PX:-ORB_PATCH_BORDER_PX] = 255
    keypoints = cv2.FastFeatureDetector_create(threshold).detect(grey, mask)
    pixels = cv2.KeyPoint_convert(keypoints).astype(float).reshape(-1, 2)
    return Corners(pixels, rays.normalised(pixels), keypoints)


class Describer:
    """ORB descriptors of chosen corners of one image, computed once each."""

    def __init__(self, grey: np.ndarray, corners: Corners):
        self._grey = grey
        self._corners = corners
        self._orb = cv2.ORB_create(edgeThreshold=ORB_PATCH_BORDER_PX, patchSize=31)
        self._known: dict[int, np.ndarray | None] = {}

    def describe(self, indices: np.ndarray) -> dict[int, np.ndarray]:
        """Descriptors of the corners ``indices`` (those ORB can describe)."""
        missing = [int(i) for i in indices if int(i) not in self._known]
        if missing:
            keypoints = [self._corners.keypoints[i] for i in missing]
            for k, i in zip(keypoints, missing):
                k.class_id = i
            described, descriptors = self._orb.compute(self._grey, keypoints)
            for i in missing:
                self._known[i] = None
            for k, d in zip(described or (), descriptors if descriptors is not None else ()):
                self._known[k.class_id] = d
        return {int(i): self._known[int(i)] for i in indices if self._known[int(i)] is not None}


def hamming(descriptors: np.ndarray, others: np.ndarray) -> np.ndarray:
    """(N,) bit distances of (N, 32) descriptors to one (32,) or to their partners (N, 32)."""
    return POPCOUNT[np.bitwise_xor(descriptors, others)].sum(axis=1).astype(int)


def search(
    predicted: np.ndarray,
    covariance: np.ndarray,
    descriptors: list[tuple[np.ndarray, np.ndarray]],
    corners: Corners,
    describer: Describer,
    gate_probability: float,
    max_hamming: int,
) -> list[tuple[int, int]]:
    """Matches ``(feature row, corner index)``: for each predicted feature (normalised
    ``predicted`` (m, 2), innovation ``covariance`` (m, 2, 2), descriptors (first, latest)), the
    corner inside its gate whose descriptor is nearest to either of its own, if within
    ``max_hamming``; a corner claimed twice goes to the closer descriptor."""
    if len(corners.normalised) == 0 or len(predicted) == 0:
        return []
    gate = chi2_quantile(gate_probability, 2)
    inverse = np.linalg.inv(covariance)
    dx = corners.normalised[None, :, 0] - predicted[:, 0, None]  # (m, N)
    dy = corners.normalised[None, :, 1] - predicted[:, 1, None]
    inside = inverse[:, 0, 0, None] * dx * dx + (inverse[:, 0, 1, None] + inverse[:, 1, 0, None]) * dx * dy + inverse[:, 1, 1, None] * dy * dy <= gate
    described = describer.describe(np.flatnonzero(inside.any(axis=0)))
    if not described:
        return []
    known = np.zeros(len(corners.normalised), dtype=bool)
    known[list(described)] = True
    rows, indices = np.nonzero(inside & known)  # candidate pairs, row by row, corners ascending
    if len(rows) == 0:
        return []
    stack = np.array([described[int(i)] for i in indices])
    first = np.array([d[0] for d in descriptors])[rows]
    latest = np.array([d[1] for d in descriptors])[rows]
    distance = np.minimum(hamming(stack, first), hamming(stack, latest))
    # each row's nearest corner (the lowest corner index of equals), then each corner's nearest
    # row (the lowest row of equals)
    order = np.lexsort((indices, distance, rows))
    best = order[np.r_[True, rows[order][1:] != rows[order][:-1]]]
    best = best[distance[best] <= max_hamming]
    if len(best) == 0:
        return []
    order = best[np.lexsort((rows[best], distance[best], indices[best]))]
    kept = order[np.r_[True, indices[order][1:] != indices[order][:-1]]]
    return sorted(zip(rows[kept].tolist(), indices[kept].tolist()))


def new_feature_corners(corners: Corners, avoid_px: np.ndarray, min_distance_px: float, count: int) -> list[int]:
    """Up to ``count`` corners, strongest first, at least ``min_distance_px`` from ``avoid_px``
    (the features already predicted in the image) and from each other."""
    if len(corners.pixels) == 0:
        return []
    clear = np.ones(len(corners.pixels), dtype=bool)
    if len(avoid_px):
        clear = np.min(np.linalg.norm(corners.pixels[:, None] - np.asarray(avoid_px)[None], axis=2), axis=1) >= min_distance_px
    chosen: list[int] = []
    for i in np.flatnonzero(clear)[np.argsort(-corners.responses[clear], kind="stable")]:
        if chosen and np.min(np.linalg.norm(corners.pixels[chosen] - corners.pixels[i], axis=1)) < min_distance_px:
            continue
        chosen.append(int(i))
        if len(chosen) == count:
            break
    return chosen
