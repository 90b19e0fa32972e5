"""What a run with the navigation stage writes: the metric trajectory as trajectory.tum, the
estimator's beside it, navigation.csv, and the SE3 (no scale) ATE beside the Sim3 one."""

import json

import numpy as np

from evp.config import Settings
from evp.io.dataset import Dataset
from evp.io.run_outputs import write_outputs
from evp.io.trajectory import read_trajectory
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
    assert len(fused) == 40 and len(visual) == 80  # metric from 2 s (tests/fusion/test_navigation_stage.py)
    assert metrics["rmse"] < 1e-6  # the top-level figures stay the estimator's (Sim3: exact poses)
    assert metrics["ate_se3_rmse"] == metrics["navigation"]["ate_se3_rmse_m"] < 0.01
    assert abs(metrics["navigation"]["scale"] / MAP_SCALE - 1.0) < 0.005 and abs(metrics["navigation"]["scale_error"]) < 0.005
    assert json.loads((tmp_path / "out" / "metrics.json").read_text())["navigation"]["sensors_used"] == ["imu", "visual"]
    rows = (tmp_path / "out" / "navigation.csv").read_text().splitlines()
    assert rows[0].startswith("timestamp,x,y,z") and len(rows) == 41 and rows[-1].split(",")[-2] == "accepted"
    assert float(rows[1].split(",")[0]) == 2.0
    assert (tmp_path / "out" / "plots" / "navigation" / "report.md").is_file()
