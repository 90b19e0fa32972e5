import cv2
import numpy as np
import pytest

from evp.errors import EvpError
from evp.types import CameraModel, Frame
from evp.vision.images import grey_image, to_grey

CAMERA = CameraModel(64, 48, 60.0, 60.0, 32.0, 24.0)


def test_to_grey_converts_bgr_keeps_grey_and_stretches_other_depths():
    rng = np.random.default_rng(0)
    bgr = rng.integers(0, 256, (48, 64, 3), dtype=np.uint8)
    assert np.array_equal(to_grey(bgr), cv2.cvtColor(bgr, cv2.COLOR_BGR2GRAY))
    grey = bgr[:, :, 0].copy()
    assert to_grey(grey) is grey
    deep = np.linspace(1000, 3000, 64 * 48).reshape(48, 64).astype(np.uint16)
    stretched = to_grey(deep)
    assert stretched.dtype == np.uint8 and (stretched.min(), stretched.max()) == (0, 255)
    assert np.all(np.diff(stretched.ravel().astype(int)) >= 0)  # the order of grey levels is kept


def test_grey_image_rejects_empty_and_wrongly_sized_frames():
    assert grey_image(Frame(0.0, np.full((48, 64, 3), 7, np.uint8)), CAMERA).shape == (48, 64)
    with pytest.raises(EvpError, match="empty image"):
        grey_image(Frame(1.5, np.zeros((0, 0), np.uint8), 3), CAMERA)
    with pytest.raises(EvpError, match="frame 4: image is 10x10, calibration is 64x48"):
        grey_image(Frame(2.0, np.zeros((10, 10), np.uint8), 4), CAMERA)
