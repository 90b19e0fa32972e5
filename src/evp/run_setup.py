"""Choosing the camera model, making the settings concrete for a dataset, and building the estimator."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from evp.config import Settings
from evp.errors import CalibrationError, DatasetError, UsageError
from evp.estimator import Estimator, GivenPoses
from evp.io.dataset import Dataset
from evp.types import CameraModel, Frame, PoseEstimate, Trajectory

_NO_IMAGE = np.zeros((1, 1), np.uint8)  # GivenPoses does not look at the images

if TYPE_CHECKING:
    from evp.fusion.map_georeference import MapGeoreference
    from evp.fusion.navigation_stage import NavigationStage
    from evp.pipeline import RunResult
    from evp.slam.gyro_prior import GyroRotations
    from evp.slam.map import Map
    from evp.wifi.positioning import WifiLocator


def camera_for(dataset: Dataset, settings: Settings) -> CameraModel:
    """The settings' calibration file or profile when given (``--camera``), for the dataset's
    image size, else the dataset's own calibration."""
    from evp.calib.profiles import configured_camera

    camera = configured_camera(settings.camera, frame_size(dataset))
    if camera is not None:
        return camera
    if dataset.camera is None:
        raise CalibrationError(
            dataset.root, "the dataset has no calibration; give --camera FILE|PROFILE (evp camera list), or camera.calibration_file in --config"
        )
    return dataset.camera


def frame_size(dataset: Dataset) -> tuple[int, int] | None:
    """(width, height) of the dataset's images: its calibration's, else its first frame's (None
    without frames)."""
    if dataset.camera is not None:
        return dataset.camera.width, dataset.camera.height
    first = next(iter(dataset.frames()), None)
    return None if first is None else (first.image.shape[1], first.image.shape[0])


def with_camera(settings: Settings, spec: str | None) -> Settings:
    """The settings with ``--camera FILE|PROFILE`` as their calibration (a file that exists, else
    a profile name), replacing whatever the settings named."""
    if spec is None:
        return settings
    from pathlib import Path

    from evp.calib.profiles import camera_from

    if Path(spec).is_file():
        given = {"calibration_file": Path(spec), "profile": None}
    else:
        camera_from(spec)  # a missing file or an unknown profile is said now, before the dataset is read
        given = {"calibration_file": None, "profile": spec}
    return settings.model_copy(update={"camera": settings.camera.model_copy(update=given)})


def median_frame_period(dataset: Dataset) -> float:
    """Median seconds between frames (a dataset of at least two frames)."""
    return float(np.median(np.diff(dataset.frame_times)))


METRIC_ESTIMATORS = ("ekf-slam",)  # metric from their own sensors: scored without a scale alignment unless eval.align says


def auto_estimator(dataset: Dataset | None) -> str:
    """What ``estimator: auto`` runs: nadir homography odometry for sparse imagery (frames more
    than 1 s apart, e.g. survey photos), else SLAM (also when no dataset is known, as live)."""
    sparse = dataset is not None and dataset.num_frames > 1 and median_frame_period(dataset) > 1.0
    return "nadir" if sparse else "slam"


def resolve_settings(settings: Settings, dataset: Dataset) -> Settings:
    """The settings with each default that depends on the dataset made concrete, so that the
    settings.yaml written beside the results says what ran: ``estimator: auto`` becomes the
    estimator it picks, ``eval.max_time_diff_s: None`` half the median frame period (each
    estimate matches at most its own frame's ground-truth stamp; 0.01 s below two frames), and a
    metric estimator's ``eval.align`` se3 unless the settings set it."""
    estimator = auto_estimator(dataset) if settings.estimator == "auto" else settings.estimator
    max_time_diff_s = settings.eval.max_time_diff_s
    if max_time_diff_s is None:
        max_time_diff_s = 0.5 * median_frame_period(dataset) if dataset.num_frames >= 2 else 0.01
    update: dict = {"max_time_diff_s": max_time_diff_s}
    if estimator in METRIC_ESTIMATORS and "align" not in settings.eval.model_fields_set:
        update["align"] = "se3"
    if not dataset.ground_truth_orientation and "rotation" not in settings.eval.model_fields_set:
        update["rotation"] = False
    evaluation = settings.eval.model_copy(update=update)
    return settings.model_copy(update={"estimator": estimator, "eval": evaluation})


def make_estimator(camera: CameraModel, settings: Settings, dataset: Dataset | None = None, T_body_cam: np.ndarray | None = None) -> Estimator:
    """The configured estimator; ``auto`` picks by the frame spacing of the dataset. Live (no
    dataset), ``T_body_cam`` is the camera's mounting the mobile station sent (its config)."""
    kind = settings.estimator
    if kind == "auto":
        kind = auto_estimator(dataset)
    if kind == "nadir":
        from evp.vo.nadir_homography import NadirHomographyOdometry

        return NadirHomographyOdometry(camera)
    if kind == "ekf-slam":
        return ekf_slam_estimator(camera, settings, dataset, T_body_cam)
    if kind == "slam":
        from evp.io.vocabulary_files import load_configured_vocabulary
        from evp.runtime.slam import build_slam

        gyro = tracking_gyro(settings, dataset, T_body_cam)
        return build_slam(camera, settings.orb, settings.slam, load_configured_vocabulary(settings.slam.vocabulary), saved_map(camera, settings), gyro)
    from evp.vo.klt_vo import KltVisualOdometry

    return KltVisualOdometry(camera, settings.vo)


def tracking_gyro(settings: Settings, dataset: Dataset | None, T_body_cam: np.ndarray | None) -> GyroRotations | None:
    """The gyro SLAM's tracking is aided by (``slam.gyro_aided_tracking``): a dataset's IMU with
    its camera extrinsic, or live the mounting the phone's config gives (its IMU samples come
    with the frames); None without either."""
    if not settings.slam.gyro_aided_tracking:
        return None
    if dataset is not None:
        T_body_cam = dataset.T_body_cam if dataset.imu else None
    if T_body_cam is None:
        return None
    from evp.slam.gyro_prior import GyroRotations

    navigation = settings.navigation
    return GyroRotations(np.asarray(T_body_cam, float)[:3, :3], navigation.gyro_noise_density, navigation.initial_gyro_bias_sigma, navigation.max_imu_gap_s)


def saved_map(camera: CameraModel, settings: Settings) -> Map | None:
    """The map ``slam.map`` names (None when it names none), its points' scale ranges for this
    camera's ORB pyramid."""
    if not settings.slam.map:
        return None
    from evp.io.map_files import load_map
    from evp.vision.orb import usable_levels

    return load_map(Path(settings.slam.map), settings.orb.scale_factor ** np.arange(usable_levels(settings.orb, camera)))


def saved_map_georeference(settings: Settings) -> MapGeoreference | None:
    """The georeference of the map ``slam.map`` names (None: no map, or one saved without)."""
    if not settings.slam.map or settings.estimator not in ("slam", "auto"):
        return None
    from evp.io.map_files import read_map_georeference

    return read_map_georeference(Path(settings.slam.map))


def ekf_slam_estimator(camera: CameraModel, settings: Settings, dataset: Dataset | None, T_body_cam: np.ndarray | None = None) -> Estimator:
    """Seed 001's EKF-SLAM: it needs the camera's mounting on the robot and the robot's wheels
    (a dataset's, checked here; live, the wheel or encoder telemetry the robot streams)."""
    from evp.ekf_slam.estimator import EkfSlamEstimator

    if dataset is not None:
        T_body_cam = dataset.T_body_cam
    if T_body_cam is None:
        where = "the dataset's camera-body extrinsic" if dataset is not None else "T_body_cam in the mobile station's config"
        raise UsageError(f"estimator ekf-slam needs the camera's mounting on the robot ({where}, T_body_cam)")
    if dataset is not None and not dataset.wheel:
        raise DatasetError(dataset.root, "estimator ekf-slam needs wheel odometry (the robot's encoders and gyro); this dataset has none")
    locator = configured_wifi_locator(settings) if dataset is None or dataset.wifi else None
    return EkfSlamEstimator(camera, np.asarray(T_body_cam, float), settings.ekf_slam, locator, settings.wifi.gate_probability)


def configured_wifi_locator(settings: Settings) -> WifiLocator | None:
    """The locator of ``wifi.method`` on the radio map ``wifi.radio_map`` names (None: it names
    none), for the EKF-SLAM to fuse WiFi scans with; its fixes are in the radio map's frame, so
    the robot's start must be placed there (``ekf_slam.start_pose``)."""
    if not settings.wifi.radio_map:
        return None
    if settings.ekf_slam.start_pose is None:
        raise UsageError(
            "wifi.radio_map is set but ekf_slam.start_pose is not: WiFi fixes are in the radio map's frame, so the robot's start must be given in it ([x m, y m, heading deg])"
        )
    from evp.io.wifi_uji import load_radio_map
    from evp.wifi.methods import method_named
    from evp.wifi.positioning import wifi_locator

    survey = load_radio_map(Path(settings.wifi.radio_map))
    method = method_named(settings.wifi.method, survey, settings.wifi)
    return wifi_locator(survey, method, settings.wifi.not_detected_dbm, settings.wifi.place_tolerance_m)


def navigation_off(dataset: Dataset, settings: Settings) -> str | None:
    """Why ``evp run`` runs no navigation stage on ``dataset`` (None: it runs one). It runs when
    ``navigation.enabled``, the estimator is SLAM (VO's map restarts at every loss; a survey has
    no IMU) and the dataset has an IMU and the camera's extrinsic to it."""
    if not settings.navigation.enabled:
        return "navigation.enabled is false"
    if settings.estimator != "slam":
        return f"the estimator is {settings.estimator}, not slam"
    if not dataset.imu:
        return "the dataset has no IMU"
    if dataset.T_body_cam is None:
        return "the dataset has no camera-IMU extrinsic"
    return None


def navigation_stage(dataset: Dataset, settings: Settings, estimator: Estimator, in_saved_map: bool | None = None) -> NavigationStage | None:
    """The navigation stage after ``estimator`` (its reset counter marks the visual jumps), or None
    when :func:`navigation_off` says why not. While the estimator's poses are in the saved map
    ``slam.map`` names (``in_saved_map``; None: as the estimator says) the stage gets the map's
    georeference."""
    if in_saved_map is None:
        in_saved_map = bool(getattr(estimator, "in_saved_map", False))
    if navigation_off(dataset, settings) is not None:
        return None
    from evp.fusion.navigation_stage import NavigationStage

    georeference = saved_map_georeference(settings) if in_saved_map else None
    return NavigationStage(dataset.T_body_cam, settings.navigation, lambda: estimator.reset_counter, settings.gps_monitor, map_georeference=georeference)


def navigation_on_refined(
    dataset: Dataset, settings: Settings, refined: Trajectory, in_saved_map: bool = False, live: Sequence[PoseEstimate] = ()
) -> tuple[RunResult, NavigationStage] | None:
    """A fresh navigation stage run over the estimator's refined trajectory (one map, after the
    final bundle adjustment and every loop correction) and the dataset's telemetry: the filter
    then fuses the poses the whole run could give, not the ones tracking had at the time (on
    EuRoC MH01 SE3 ATE 6.6 mm against 10.4 mm live). None when no stage runs on ``dataset``.
    ``in_saved_map``: the trajectory is in the saved map ``slam.map`` names (SLAM never left it).
    ``live``: the estimates answered live, whose scene depths the refined poses keep (a refinement
    moves a pose by far less than the depth it was seen at)."""
    from evp.pipeline import run_frames

    depth_at = {e.timestamp: e.scene_depth for e in live if e.scene_depth is not None}
    depths = np.array([depth_at.get(float(t), np.nan) for t in refined.timestamps]) if depth_at else None
    poses = GivenPoses(refined.timestamps, refined.poses, scene_depths=depths)
    stage = navigation_stage(dataset, settings, poses, in_saved_map)
    if stage is None:
        return None
    frames = (Frame(float(t), _NO_IMAGE, i) for i, t in enumerate(dataset.frame_times))
    return run_frames(poses, frames, stages=[stage], telemetry=dataset.telemetry()), stage


def estimate(
    dataset: Dataset, settings: Settings, advance=lambda frames: None, realtime_speed: float | None = None
) -> tuple[RunResult, NavigationStage | None, Estimator]:
    """What ``evp run`` computes on ``dataset`` with concrete ``settings`` (:func:`resolve_settings`):
    the estimator and its navigation stage over every frame (``realtime_speed``: paced as the base
    station would be, dropping frames; a real-time replay has no spare time for the reference ORB).
    Returns the run, the stage and the estimator (:func:`refine_and_write` finishes with them)."""
    from evp.pipeline import run_dataset

    estimator = make_estimator(camera_for(dataset, settings), settings, dataset)
    navigation = navigation_stage(dataset, settings, estimator)
    reference_orb = None if realtime_speed is not None else settings.orb.n_features
    result = run_dataset(dataset, estimator, advance, reference_orb, realtime_speed, stages=[navigation] if navigation is not None else [])
    return result, navigation, estimator


def refine_and_write(result: RunResult, navigation: NavigationStage | None, estimator: Estimator, dataset: Dataset, settings: Settings, out) -> dict:
    """The end of ``evp run``: the refinement after the last frame (a survey adjustment or a global
    bundle adjustment; seconds), the navigation stage again on the refined trajectory when the
    settings ask for it, and the outputs in ``out``; returns the metrics written."""
    from evp.io.run_outputs import write_outputs

    refined_navigation = offline_navigation(result, navigation, estimator, dataset, settings)
    return write_outputs(result, dataset, settings, out, navigation, refined_navigation)


def offline_navigation(
    result: RunResult, navigation: NavigationStage | None, estimator: Estimator, dataset: Dataset, settings: Settings
) -> tuple[RunResult, NavigationStage] | None:
    """After the last frame: the estimator's refinement (a global bundle adjustment; seconds),
    then, when the run had a navigation stage and ``navigation.refine_offline`` asks for it, the
    stage again over the refined trajectory (:func:`navigation_on_refined`); None otherwise."""
    result.final_trajectory()
    if navigation is None or not settings.navigation.refine_offline or result.refined is None or len(result.refined) < 2:
        return None
    return navigation_on_refined(dataset, settings, result.refined, bool(getattr(estimator, "in_saved_map", False)), result.estimates)
