"""What a run with the navigation stage writes: the metric trajectory as trajectory.tum, the
estimator's beside it, navigation.csv, and the SE3 (no scale) ATE beside the Sim3 one."""

import json

import numpy as np

from evp.config import Settings
from evp.io.dataset import Dataset
from evp.io.run_outputs import write_outputs
from evp.io.trajectory import read_trajectory
from evp.run_setup import navigation_on_refined
from evp.types import PoseEstimate, TrackingState, Trajectory
from tests.fusion.inertial_trajectory import SinusoidTrajectory, imu_times
from tests.fusion.test_navigation_filter import MAP_SCALE, T_BODY_CAM
from tests.fusion.test_navigation_stage import FRAME_RATE, _run, map_pose


def test_a_navigation_run_writes_the_metric_trajectory_and_its_se3_ate(tmp_path):
    trajectory = SinusoidTrajectory()
    times = np.arange(0.0, 4.0, 1.0 / FRAME_RATE)
    estimates = [PoseEstimate(float(t), map_pose(trajectory, t), TrackingState.OK) for t in times]
    stage, result = _run(estimates, trajectory.imu(imu_times(4.0)))
    truth = Trajectory.from_poses(np.array([trajectory.pose(t) @ T_BODY_CAM for t in times]), times, "truth")
    dataset = Dataset("synthetic", "test", tmp_path, frame_times=times, ground_truth=truth)
    settings = Settings().model_copy(update={"eval": Settings().eval.model_copy(update={"max_time_diff_s": 0.01})})
    metrics = write_outputs(result, dataset, settings, tmp_path / "out", stage)
    fused, visual = read_trajectory(tmp_path / "out" / "trajectory.tum"), read_trajectory(tmp_path / "out" / "trajectory_visual.tum")
    assert len(fused) == 60 and len(visual) == 80  # metric from 1 s (tests/fusion/test_navigation_stage.py)
    assert metrics["rmse"] < 1e-6  # the top-level figures stay the estimator's (Sim3: exact poses)
    assert metrics["ate_se3_rmse"] == metrics["navigation"]["ate_se3_rmse_m"] < 0.01
    assert abs(metrics["navigation"]["scale"] / MAP_SCALE - 1.0) < 0.005 and abs(metrics["navigation"]["scale_error"]) < 0.005
    assert json.loads((tmp_path / "out" / "metrics.json").read_text())["navigation"]["sensors_used"] == ["imu", "visual"]
    rows = (tmp_path / "out" / "navigation.csv").read_text().splitlines()
    assert rows[0].startswith("timestamp,x,y,z") and len(rows) == 61 and rows[-1].split(",")[-2] == "accepted"
    assert float(rows[1].split(",")[0]) == 1.0
    assert (tmp_path / "out" / "plots" / "navigation" / "report.md").is_file()


def test_the_stage_runs_again_on_the_refined_trajectory(tmp_path):
    """Live poses with a 2 cm jitter, refined ones exact: trajectory.tum is the refined pass's,
    better than the fused poses as answered live, which go to trajectory_live.tum."""
    trajectory = SinusoidTrajectory()
    times = np.arange(0.0, 4.0, 1.0 / FRAME_RATE)
    rng = np.random.default_rng(3)
    exact = np.array([map_pose(trajectory, t) for t in times])
    jittered = exact.copy()
    jittered[:, :3, 3] += rng.normal(0.0, 0.02 / MAP_SCALE, (len(times), 3))
    imu = trajectory.imu(imu_times(4.0))
    stage, result = _run([PoseEstimate(float(t), T, TrackingState.OK) for t, T in zip(times, jittered)], imu)
    truth = Trajectory.from_poses(np.array([trajectory.pose(t) @ T_BODY_CAM for t in times]), times, "truth")
    dataset = Dataset("synthetic", "test", tmp_path, frame_times=times, ground_truth=truth, imu=imu, T_body_cam=T_BODY_CAM)
    settings = Settings().model_copy(update={"estimator": "slam", "eval": Settings().eval.model_copy(update={"max_time_diff_s": 0.01})})
    refined = navigation_on_refined(dataset, settings, Trajectory.from_poses(exact, times, "refined"))
    metrics = write_outputs(result, dataset, settings, tmp_path / "out", stage, refined)
    section = metrics["navigation"]
    assert len(read_trajectory(tmp_path / "out" / "trajectory_live.tum")) == section["live_metric_frames"] == len(result.metric_trajectory())
    assert section["ate_se3_rmse_m"] < 0.5 * section["live_ate_se3_rmse_m"]
    assert section["ate_se3_rmse_m"] == metrics["ate_se3_rmse"] < 0.01
