"""The 8-bit grey image every estimator works on, with the checks a frame must pass first."""

from __future__ import annotations

import cv2
import numpy as np

from evp.errors import FrameError
from evp.types import CameraModel, Frame


def grey_image(frame: Frame, camera: CameraModel) -> np.ndarray:
    """8-bit grey image of ``frame``; an empty image or one whose size is not the calibration's
    raises a specific error (the caller skips the frame, nothing is estimated from it)."""
    image = frame.image
    if image is None or image.size == 0:
        raise FrameError(f"frame {frame.index} at t={frame.timestamp}: empty image")
    if image.shape[0] != camera.height or image.shape[1] != camera.width:
        raise FrameError(f"frame {frame.index}: image is {image.shape[1]}x{image.shape[0]}, calibration is {camera.width}x{camera.height}")
    return to_grey(image)


def to_grey(image: np.ndarray) -> np.ndarray:
    """8-bit grey version of a grey or BGR image (a grey uint8 image is returned as it is); other
    depths are stretched to 0..255, since feature detectors and board finders take 8 bits only."""
    grey = image if image.ndim == 2 else cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
    return grey if grey.dtype == np.uint8 else cv2.normalize(grey, None, 0, 255, cv2.NORM_MINMAX).astype(np.uint8)
