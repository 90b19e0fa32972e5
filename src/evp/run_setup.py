"""Choosing the camera model and building the estimator for a run from the settings."""

from __future__ import annotations

import numpy as np

from evp.config import Settings
from evp.errors import CalibrationError
from evp.estimator import Estimator
from evp.io.dataset import Dataset
from evp.types import CameraModel


def camera_for(dataset: Dataset, settings: Settings) -> CameraModel:
    """The settings' calibration file or profile when given, else the dataset's own calibration."""
    from evp.calib.camera_files import read_camera
    from evp.calib.profiles import load_profile

    if settings.camera.calibration_file is not None:
        return read_camera(settings.camera.calibration_file)
    if settings.camera.profile:
        return load_profile(settings.camera.profile)
    if dataset.camera is None:
        raise CalibrationError(dataset.root, "the dataset has no calibration; give camera.calibration_file or camera.profile in --config")
    return dataset.camera


def make_estimator(camera: CameraModel, settings: Settings, dataset: Dataset | None = None) -> Estimator:
    """The configured estimator; ``auto`` picks by the frame spacing of the dataset."""
    kind = settings.estimator
    if kind == "auto":
        sparse = dataset is not None and dataset.num_frames > 1 and float(np.median(np.diff(dataset.frame_times))) > 1.0
        kind = "nadir" if sparse else "slam"
    if kind == "nadir":
        from evp.vo.nadir_homography import NadirHomographyOdometry

        return NadirHomographyOdometry(camera)
    if kind == "slam":
        from evp.runtime.slam import build_slam

        return build_slam(camera, settings.orb, settings.slam)
    from evp.vo.klt_vo import KltVisualOdometry

    return KltVisualOdometry(camera, settings.vo)
