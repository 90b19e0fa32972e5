"""Seed 001's EKF-SLAM as an :class:`~evp.estimator.Estimator`: wheel samples arrive through
:meth:`observe` (the pipeline hands every telemetry record over in time order), frames through
:meth:`feed`. Its poses are metric from the start (the wheels measure metres) in the world of the
robot's start pose, or in the radio map's frame when ``ekf_slam.start_pose`` places the start there.

With a WiFi locator (``wifi.radio_map``), each WiFi scan is located in the radio map and fused as
a weak absolute position (:meth:`~evp.ekf_slam.filter.EkfSlamFilter.position_fix`, its sigma the
locator's measured error); a scan that heard no access point of the radio map is skipped, with
a warning for the first and a count of all."""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from evp.config import EkfSlamSettings
from evp.ekf_slam.slam import FrameReport, WheelVisualSlam
from evp.errors import FrameError
from evp.estimator import Estimator
from evp.types import CameraModel, Frame, PoseEstimate, TrackingState, WheelOdometry, WifiScan
from evp.vision.images import to_grey
from evp.wifi.positioning import WifiLocator

REPORTED_WARNINGS = 20  # metrics.json lists this many warnings, then counts the rest


class EkfSlamEstimator(Estimator):
    def __init__(
        self, camera: CameraModel, T_body_cam: np.ndarray, settings: EkfSlamSettings, wifi: WifiLocator | None = None, wifi_gate_probability: float = 0.9973
    ):
        self.camera = camera
        self.settings = settings
        self.slam = WheelVisualSlam(camera, T_body_cam, settings)
        if settings.start_pose is not None:
            x, y, heading_deg = settings.start_pose
            self.slam.filter.set_start(x, y, math.radians(heading_deg), settings.start_position_sigma_m, math.radians(settings.start_heading_sigma_deg))
        self.wifi = wifi
        self.wifi_gate_probability = wifi_gate_probability
        self.wifi_unlocated = 0  # scans that heard no access point of the radio map
        self.frames: list[FrameReport] = []
        self.state_sizes: list[int] = []  # state dimension after each frame
        self.feature_counts: list[int] = []  # features in the state after each frame

    def observe(self, record: object) -> None:
        if isinstance(record, WheelOdometry):
            speed = record.forward_speed_m_s
            if not math.isfinite(speed) and record.wheel_speeds_m_s:
                speed = float(np.mean(record.wheel_speeds_m_s))
            self.slam.wheels(record.timestamp, speed, record.yaw_rate_rad_s)
        elif isinstance(record, WifiScan) and self.wifi is not None:
            self._wifi(record)

    def _wifi(self, scan: WifiScan) -> None:
        fix = self.wifi.fix(scan.timestamp, scan.rssi_dbm)
        if fix is None:
            if not self.wifi_unlocated:
                self.slam.filter.warnings.append(f"WiFi scan at {scan.timestamp:.3f} s heard no access point of the radio map: skipped (later ones counted)")
            self.wifi_unlocated += 1
            return
        self.slam.filter.position_fix(fix.timestamp, fix.position, fix.sigma_m, self.wifi_gate_probability)

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
                **self._wifi_report(),
            }
        }

    def _wifi_report(self) -> dict[str, Any]:
        if self.wifi is None:
            return {}
        fixes = self.slam.filter.fixes
        return {
            "wifi": {
                "method": self.wifi.method.name,
                "k": self.wifi.method.k,
                "sigma_m": self.wifi.sigma_m,
                "fixes_accepted": sum(1 for f in fixes if f.accepted),
                "fixes_gated": sum(1 for f in fixes if not f.accepted),
                "scans_without_known_access_point": self.wifi_unlocated,
                "mean_nis": float(np.mean([f.nis for f in fixes])) if fixes else None,
            }
        }
