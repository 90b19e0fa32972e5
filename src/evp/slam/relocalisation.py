"""Appearance-based keyframe retrieval for relocalisation.

The global descriptor is a small blurred, zero-mean, unit-norm thumbnail of the image (PTAM's
relocaliser): built from the image itself, nothing to train or download, and robust to the
moderate viewpoint changes a robot sees when it returns to a place. Retrieval ranks keyframes by
normalised cross-correlation; the candidates are then verified geometrically (PnP RANSAC on
descriptor matches, then guided search), so a wrong candidate costs time, never a wrong pose.
"""

from __future__ import annotations

import cv2
import numpy as np

THUMBNAIL_SIZE = (40, 30)


def thumbnail(grey: np.ndarray) -> np.ndarray:
    small = cv2.resize(grey, THUMBNAIL_SIZE, interpolation=cv2.INTER_AREA).astype(np.float32)
    small = cv2.GaussianBlur(small, (0, 0), 1.5).ravel()
    small -= small.mean()
    return small / max(float(np.linalg.norm(small)), 1e-6)


def rank_keyframes(query: np.ndarray, kf_ids: list[int], thumbnails: np.ndarray, count: int) -> list[int]:
    """The ``count`` keyframes whose thumbnails correlate best with ``query``."""
    if not kf_ids:
        return []
    scores = thumbnails @ query
    order = np.argsort(-scores)[:count]
    return [kf_ids[i] for i in order]
