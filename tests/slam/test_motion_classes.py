"""Motion and camera classes the engine was not tuned on, rendered with exact ground truth and run
with the default configuration: a car driving a town road at 20 m/s seen at 10 Hz (2 m between
frames, near points leaving the view at every frame), and a hand-held pan (the view turns up to
50 degrees a second while the phone moves 0.3 m/s). Issue 29's targets on short clips
(bench/motion_classes.py runs the long ones; bench/camera_models.py the fisheye, whose renders
are too slow for the suite)."""

import numpy as np

from evp.config import EvalSettings, Settings
from evp.eval.evaluate import evaluate
from evp.io.registry import open_dataset
from evp.pipeline import run_dataset
from evp.run_setup import make_estimator
from evp.sim.generate import generate
from evp.sim.scenarios import SimOptions


def _run(folder):
    dataset = open_dataset(folder)
    result = run_dataset(dataset, make_estimator(dataset.camera, Settings(estimator="slam"), dataset))  # with its gyro, as evp run
    trajectory = result.final_trajectory()
    period = float(np.median(np.diff(trajectory.timestamps)))
    rmse = evaluate(dataset.ground_truth, trajectory, EvalSettings(align="sim3", max_time_diff_s=period / 2)).summary()["rmse"]
    return dataset, result, trajectory, rmse


def _path_covered(dataset, trajectory):
    gt = dataset.ground_truth
    covered = (gt.timestamps >= trajectory.timestamps[0]) & (gt.timestamps <= trajectory.timestamps[-1])
    return np.linalg.norm(np.diff(gt.positions[covered], axis=0), axis=1).sum()


def test_a_car_at_20_m_s_seen_at_10_hz_starts_within_a_second_and_keeps_tracking(tmp_path):
    generate("road-drive", SimOptions(duration_s=4.0, fps=10.0, seed=1), tmp_path, workers=2)
    dataset, result, trajectory, rmse = _run(tmp_path)
    stamps = [estimate.timestamp for estimate in result.estimates]
    assert stamps[result.init_frame] - stamps[0] <= 1.0
    assert len(trajectory) >= 0.95 * len(stamps)  # the frames before the start are localised afterwards
    path = _path_covered(dataset, trajectory)
    assert path > 60.0  # about 80 m driven
    assert rmse <= 0.01 * path


def test_a_down_looking_camera_climbing_maps_the_ground_it_zooms_out_over(tmp_path):
    """Seed 000's square: take-off over paving, climbing to 12 m, then cruising. Climbing along
    the optical axis keeps every point of the reference keyframe in view, so the tracked share
    never falls and, before keyframes followed the tracked depth, none was taken from 7 m up to
    the cruise: tracking rested on a shrinking patch of the image and drifted metres within
    seconds of the cruise starting (13 m by 16 s)."""
    generate("drone-square-loops", SimOptions(duration_s=16.0, fps=15.0, seed=1), tmp_path, workers=2)
    dataset, result, trajectory, rmse = _run(tmp_path)
    stamps = [estimate.timestamp for estimate in result.estimates]
    assert len(trajectory) >= 0.95 * (len(stamps) - result.init_frame)
    path = _path_covered(dataset, trajectory)
    assert path > 12.0  # the climb and the first metres of the cruise
    assert rmse <= 0.01 * path


def test_a_hand_held_pan_keeps_tracking_as_the_view_turns_into_the_unseen_side(tmp_path):
    # seed 2: after sweeping 80 degrees and back, the view turns fast into the room's unseen side.
    # Against walls 2-4 m away a turn and a sideways step of the phone look alike; vision alone
    # traded one for the other, its keyframes' new points failed the parallax test and the turn
    # was lost (67 % tracked, ATE 4.2 cm). The gyro's rotation as tracking's prior keeps it.
    generate("handheld-pan", SimOptions(duration_s=10.0, fps=30.0, seed=2), tmp_path, workers=2)
    dataset, result, trajectory, rmse = _run(tmp_path)
    assert result.estimator.report()["gyro_aided_tracking"]  # the render's IMU, through its extrinsic
    stamps = [estimate.timestamp for estimate in result.estimates]
    assert stamps[result.init_frame] - stamps[0] <= 2.0  # the pan starts after 1 s
    assert len(trajectory) >= 0.95 * len(stamps)
    path = _path_covered(dataset, trajectory)
    assert path > 1.5  # the phone's arc, about 1.7 m
    assert rmse <= 0.02 * path
