"""Seed 001's EKF-SLAM as an :class:`~evp.estimator.Estimator`: wheel samples arrive through
:meth:`observe` (the pipeline hands every telemetry record over in time order), frames through
:meth:`feed`. Its poses are metric from the start (the wheels measure metres) in the world of the
robot's start pose."""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from evp.config import EkfSlamSettings
from evp.ekf_slam.slam import FrameReport, WheelVisualSlam
from evp.errors import FrameError
from evp.estimator import Estimator
from evp.types import CameraModel, Frame, PoseEstimate, TrackingState, WheelOdometry
from evp.vision.images import to_grey

REPORTED_WARNINGS = 20  # metrics.json lists this many warnings, then counts the rest


class EkfSlamEstimator(Estimator):
    def __init__(self, camera: CameraModel, T_body_cam: np.ndarray, settings: EkfSlamSettings):
        self.camera = camera
        self.settings = settings
        self.slam = WheelVisualSlam(camera, T_body_cam, settings)
        self.frames: list[FrameReport] = []
        self.state_sizes: list[int] = []  # state dimension after each frame
        self.feature_counts: list[int] = []  # features in the state after each frame

    def observe(self, record: object) -> None:
        if isinstance(record, WheelOdometry):
            speed = record.forward_speed_m_s
            if not math.isfinite(speed) and record.wheel_speeds_m_s:
                speed = float(np.mean(record.wheel_speeds_m_s))
            self.slam.wheels(record.timestamp, speed, record.yaw_rate_rad_s)

    def feed(self, frame: Frame) -> PoseEstimate:
        grey = to_grey(frame.image)
        if grey.shape != (self.camera.height, self.camera.width):
            raise FrameError(f"frame {frame.index}: {grey.shape[1]}x{grey.shape[0]} is not the calibrated {self.camera.width}x{self.camera.height}")
        report = self.slam.image(frame.timestamp, grey)
        self.frames.append(report)
        self.state_sizes.append(len(self.slam.filter.x))
        self.feature_counts.append(len(self.slam.filter.features))
        R_wc, centre = self.slam.filter.camera_pose()
        pose = np.eye(4)
        pose[:3, :3], pose[:3, 3] = R_wc, centre
        quality = int(min(100, 100 * report.matched / self.settings.min_matched_features))
        return PoseEstimate(frame.timestamp, pose, TrackingState.OK, quality, metric=True, scale_known=True)

    def report(self) -> dict[str, Any]:
        flt = self.slam.filter
        matched = [r.matched for r in self.frames] or [0]
        warnings = flt.warnings
        return {
            "ekf_slam": {
                "features_final": len(flt.features),
                "euclidean_features_final": sum(1 for f in flt.features if not f.inverse_depth),
                "features_max": max(self.feature_counts, default=0),
                "state_size_max": max(self.state_sizes, default=len(flt.x)),
                "matched_per_frame_median": float(np.median(matched)),
                "updates": len(flt.updates),
                "mean_nis_per_dof": float(sum(u.nis for u in flt.updates) / max(1, sum(u.dof for u in flt.updates))),
                "inconsistent_at_end": flt.inconsistent,
                "warnings": warnings[:REPORTED_WARNINGS],
                "warnings_count": len(warnings),
            }
        }
