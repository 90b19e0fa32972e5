"""WiFi fixes in the EKF-SLAM's filter, on exact synthetic data: wheels with known errors, fixes at
the true positions with a stated sigma, a radio map of a noise-free path-loss room."""

from __future__ import annotations

import math

import numpy as np
import pytest

from evp.config import EkfSlamSettings, Settings
from evp.ekf_slam.estimator import EkfSlamEstimator
from evp.ekf_slam.filter import EkfSlamFilter
from evp.errors import UsageError
from evp.fusion.innovation import UpdateStatus
from evp.sim.landmark_drive import CAMERA_OFFSET, FORWARD_CAMERA, ring_loop
from evp.types import CameraModel, WheelOdometry, WifiScan
from evp.wifi.fingerprints import Fingerprints
from evp.wifi.knn import KnnMethod
from evp.wifi.positioning import RAYLEIGH_MEAN, scan_rss, wifi_locator
from evp.wifi.tuning import leave_one_place_out_error

ACCESS_POINTS = np.array([[0.0, 0.0], [4.0, 0.0], [0.0, 4.0]])
NAMES = ("ap0", "ap1", "ap2")


def room_survey() -> Fingerprints:
    """A 5 x 5 grid of 1 m spacing, the RSS of a noise-free log-distance path loss."""
    nodes = np.array([(x, y) for x in range(5) for y in range(5)], dtype=float)
    distance = np.maximum(np.linalg.norm(nodes[:, None] - ACCESS_POINTS[None], axis=2), 0.1)
    return Fingerprints(-40.0 - 25.0 * np.log10(distance), nodes, np.zeros(len(nodes), dtype=int), NAMES)


def drive_with_fixes(scale: float, bias: float, sigma_m: float | None) -> tuple[np.ndarray, EkfSlamFilter]:
    """Twice round the 1 m circle, the wheels' speeds times ``scale`` and the gyro off by ``bias``;
    a fix at the true position every second when ``sigma_m`` is given. The position errors at
    each second, and the filter."""
    scene = ring_loop()
    flt = EkfSlamFilter(FORWARD_CAMERA, CAMERA_OFFSET, EkfSlamSettings(), 500.0)
    errors = []
    for k, t in enumerate(scene.times):
        flt.predict(t, scene.speeds[k] * scale, scene.yaw_rates[k] + bias)
        if k % 50 == 0 and k:
            if sigma_m is not None:
                flt.position_fix(t, scene.poses[k, :2], sigma_m, 0.9973)
            errors.append(np.linalg.norm(flt.x[:2] - scene.poses[k, :2]))
    return np.array(errors), flt


def test_fixes_bound_the_drift_of_degraded_wheels():
    """Wheels 10 % fast and a 0.02 rad/s gyro bias drift 0.8 m in 42 s and grow on; exact fixes
    with a 0.3 m sigma hold the error under 0.2 m all along (the filter, whose wheel noise is
    2 cm/s, learns its error slowly), every fix passes the gate."""
    drift, _ = drive_with_fixes(1.1, 0.02, None)
    bounded, flt = drive_with_fixes(1.1, 0.02, 0.3)
    assert drift[-1] > 0.7 and drift[-1] > drift[len(drift) // 2]
    assert bounded.max() < 0.2 and bounded[-10:].max() < 0.15
    assert len(flt.fixes) == len(bounded) and all(f.accepted for f in flt.fixes)
    assert all(f.kind == "wifi" and f.residual.shape == (2,) for f in flt.fixes)


def test_a_fix_beyond_the_gate_is_not_fused():
    flt = EkfSlamFilter(FORWARD_CAMERA, CAMERA_OFFSET, EkfSlamSettings(), 500.0)
    flt.set_start(0.0, 0.0, 0.0, 0.1, 0.01)
    before = flt.x.copy()
    innovation = flt.position_fix(0.0, np.array([20.0, 0.0]), 1.0, 0.9973)
    assert innovation.status is UpdateStatus.GATED and innovation.nis > innovation.threshold
    np.testing.assert_array_equal(flt.x, before)
    assert flt.position_fix(0.0, np.array([0.5, 0.0]), 1.0, 0.9973).accepted
    assert 0.0 < flt.x[0] < 0.5


def test_locator_sigma_is_the_measured_error_as_a_per_axis_sigma():
    survey = room_survey()
    method = KnnMethod("nn1", k=1)
    locator = wifi_locator(survey, method, -105.0, 0.05)
    assert locator.sigma_m == pytest.approx(leave_one_place_out_error(survey, method, -105.0, 0.05) / RAYLEIGH_MEAN)
    assert RAYLEIGH_MEAN == pytest.approx(math.sqrt(math.pi / 2))
    exact = dict(zip(NAMES, survey.rss[7]))
    np.testing.assert_allclose(locator.fix(1.0, exact).position, survey.positions[7])  # a surveyed place is found exactly
    assert locator.fix(1.0, {"unknown": -50.0}) is None
    np.testing.assert_array_equal(scan_rss({"ap1": -60.0, "other": -30.0}, NAMES), [np.nan, -60.0, np.nan])


def test_estimator_skips_scans_without_a_known_access_point_and_counts_them():
    camera = CameraModel(64, 48, 50.0, 50.0, 32.0, 24.0)
    locator = wifi_locator(room_survey(), KnnMethod("nn1", k=1), -105.0, 0.05)
    T_body_cam = np.eye(4)
    T_body_cam[:3, :3], T_body_cam[:3, 3] = FORWARD_CAMERA, CAMERA_OFFSET
    settings = EkfSlamSettings(start_pose=[1.0, 1.0, 90.0])
    estimator = EkfSlamEstimator(camera, T_body_cam, settings, locator)
    assert estimator.slam.filter.x[:3] == pytest.approx([1.0, 1.0, math.pi / 2])
    estimator.observe(WheelOdometry(0.0, (0.0, 0.0), 0.0, 0.0))
    for t in (0.5, 1.0):
        estimator.observe(WifiScan(t, {"elsewhere": -50.0}))
    estimator.observe(WifiScan(1.5, dict(zip(NAMES, room_survey().rss[6]))))
    report = estimator.report()["ekf_slam"]
    assert report["wifi"]["scans_without_known_access_point"] == 2
    assert report["wifi"]["fixes_accepted"] == 1
    assert sum("heard no access point" in w for w in report["warnings"]) == 1


def test_a_radio_map_needs_the_start_in_its_frame(tmp_path):
    from evp.run_setup import configured_wifi_locator

    with pytest.raises(UsageError, match="ekf_slam.start_pose"):
        configured_wifi_locator(Settings.model_validate({"wifi": {"radio_map": str(tmp_path / "map.npz")}}))
