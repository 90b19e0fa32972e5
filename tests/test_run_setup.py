"""run_setup: the settings made concrete for a dataset, and the estimator they name."""

from pathlib import Path

import numpy as np
import pytest

from evp.config import EvalSettings, Settings
from evp.eval.evaluate import evaluate
from evp.io.dataset import Dataset
from evp.run_setup import resolve_settings
from evp.types import Trajectory


def _dataset(frame_times) -> Dataset:
    return Dataset("test", "test", Path("."), frame_times=np.asarray(frame_times, dtype=float))


def test_auto_becomes_the_estimator_that_runs():
    assert resolve_settings(Settings(), _dataset(np.arange(10) / 30.0)).estimator == "slam"
    assert resolve_settings(Settings(), _dataset(np.arange(10) * 10.0)).estimator == "nadir"  # survey photos 10 s apart
    assert resolve_settings(Settings(estimator="klt-vo"), _dataset(np.arange(10) * 10.0)).estimator == "klt-vo"


def test_time_tolerance_defaults_to_half_the_median_frame_period():
    times = np.array([0.0, 0.25, 0.75, 1.0, 1.5, 1.75])  # steps 0.25, 0.5, 0.25, 0.5, 0.25: exact in binary
    resolved = resolve_settings(Settings(), _dataset(times))
    assert resolved.eval.max_time_diff_s == 0.125
    assert resolve_settings(Settings(), _dataset([0.0])).eval.max_time_diff_s == 0.01
    given = Settings(eval=EvalSettings(max_time_diff_s=0.003))
    assert resolve_settings(given, _dataset(times)).eval.max_time_diff_s == 0.003
    assert Settings().eval.max_time_diff_s is None and Settings().estimator == "auto"  # the input is left as it was


def test_evaluate_refuses_an_unresolved_tolerance():
    trajectory = Trajectory.from_poses(np.tile(np.eye(4), (5, 1, 1)), np.arange(5.0))
    with pytest.raises(ValueError, match="unresolved"):
        evaluate(trajectory, trajectory, EvalSettings())


def test_slam_tracking_takes_the_gyro_when_the_dataset_has_an_imu_and_the_cameras_mounting():
    from evp.run_setup import tracking_gyro
    from evp.types import ImuSample

    mounted = np.eye(4)
    mounted[:3, :3] = [[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]]
    imu = [ImuSample(0.0, (0.0, 0.0, 0.0), (0.0, 0.0, 9.81))]
    with_both = Dataset("test", "test", Path("."), frame_times=np.arange(3.0), imu=imu, T_body_cam=mounted)
    gyro = tracking_gyro(Settings(), with_both, None)
    assert np.array_equal(gyro.R_imu_cam, mounted[:3, :3])
    assert gyro.noise_density == Settings().navigation.gyro_noise_density and gyro.bias_sigma == Settings().navigation.initial_gyro_bias_sigma
    assert gyro.max_gap_s == Settings().navigation.max_imu_gap_s
    assert tracking_gyro(Settings(), Dataset("test", "test", Path("."), frame_times=np.arange(3.0), imu=imu), None) is None  # no mounting
    assert tracking_gyro(Settings(), Dataset("test", "test", Path("."), frame_times=np.arange(3.0), T_body_cam=mounted), None) is None  # no IMU
    assert tracking_gyro(Settings(slam={"gyro_aided_tracking": False}), with_both, None) is None
    assert tracking_gyro(Settings(), None, mounted) is not None  # live: the phone's config gives the mounting
    assert tracking_gyro(Settings(), None, None) is None
