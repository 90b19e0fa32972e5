"""Figures in the plane the path lies in, and no rotation figures from a position-only reference."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from evp.cli.evaluation import says_position_only
from evp.config import EvalSettings, Settings
from evp.eval.evaluate import evaluate
from evp.eval.plane import motion_plane
from evp.eval.plots import write_plots
from evp.eval.report import markdown_summary
from evp.io.dataset import Dataset
from evp.run_setup import resolve_settings
from evp.types import Trajectory


def _drive(n=60, up_axis=1):
    """A car-like loop on the ground plane of a frame whose ``up_axis`` is vertical."""
    t = np.linspace(0, 2 * np.pi, n)
    ground = np.column_stack([50 * np.cos(t), 30 * np.sin(t)])
    positions = np.insert(ground, up_axis, 0.02 * np.sin(5 * t), axis=1)
    quats = Rotation.from_euler("y", t[:, None]).as_quat()
    return Trajectory(positions, quats, t, "drive")


def test_a_kitti_drive_is_drawn_in_x_z():
    assert motion_plane(_drive(up_axis=1).positions).name == "xz"
    assert motion_plane(_drive(up_axis=2).positions).name == "xy"
    assert motion_plane(_drive(up_axis=1).positions, "xy").name == "xy"  # the user's choice wins


def test_a_straight_drive_is_seen_from_above_not_from_the_side():
    t = np.linspace(0, 60, 51)
    kitti = np.column_stack([-0.015 * t, -0.02 * t, t])  # KITTI 06's start: descends more than it swerves
    assert motion_plane(kitti).name == "xz"
    enu = np.column_stack([t, 0.01 * t, 0.02 * t])  # along east, climbing a little
    assert motion_plane(enu).name == "xy"


def test_a_tilted_path_uses_its_principal_plane():
    positions = _drive(up_axis=2).positions @ Rotation.from_euler("x", 40, degrees=True).as_matrix().T
    plane = motion_plane(positions)
    assert plane.name == "principal"
    projected = plane.project(positions - positions.mean(axis=0))
    assert np.ptp(projected[:, 0]) == pytest.approx(100, rel=0.01)


def test_position_only_reference_gets_no_rotation_or_rpe(tmp_path):
    ref = _drive(up_axis=2)
    gps = Trajectory(ref.positions, np.tile([0.0, 0.0, 0.0, 1.0], (len(ref), 1)), ref.timestamps, "gps")
    est = Trajectory(ref.positions + 0.1, ref.quats_xyzw, ref.timestamps, "est")
    summary = evaluate(gps, est, EvalSettings(max_time_diff_s=0.01, rotation=False)).summary()
    assert "ape_rotation_deg" not in summary and "rpe" not in summary and summary["reference_orientation"] is False
    full = evaluate(gps, est, EvalSettings(max_time_diff_s=0.01))
    assert full.summary()["ape_rotation_deg"]["max"] > 90  # what the placeholder orientation would give
    assert [p.name for p in write_plots(full, tmp_path)][0] == "top_view.png"


def test_position_only_is_taken_from_the_dataset_and_the_file_header(tmp_path):
    dataset = Dataset("survey", "exif-photos", tmp_path, None, np.arange(3.0))
    dataset.ground_truth_orientation = False
    assert resolve_settings(Settings(), dataset).eval.rotation is False
    assert resolve_settings(Settings(eval=EvalSettings(rotation=True)), dataset).eval.rotation is True  # typed: kept
    path = tmp_path / "gt.txt"
    path.write_text("# t east north up qx qy qz qw  -- POSITION ONLY: quaternion is a placeholder\n0 0 0 0 0 0 0 1\n")
    assert says_position_only(path)
    path.write_text("0 0 0 0 0 0 0 1\n")
    assert not says_position_only(path)


def test_a_straight_path_gets_no_rotation_error_from_its_arbitrary_alignment(tmp_path):
    t = np.linspace(0, 3, 40)
    slider = Trajectory(np.column_stack([t, 0 * t, 0 * t]), np.tile([0.0, 0.0, 0.0, 1.0], (40, 1)), t, "slider")
    est = Trajectory(2 * slider.positions + 0.3, Rotation.from_euler("x", 50, degrees=True).as_quat()[None].repeat(40, 0), t, "est")
    result = evaluate(slider, est, EvalSettings(max_time_diff_s=0.01))
    summary = result.summary()
    assert result.alignment.degenerate and summary["reference_orientation"] is True
    assert "ape_rotation_deg" not in summary and "rpe" in summary  # relative rotations need no alignment
    assert "no APE rotation" in markdown_summary(result, "gt", "est") and "APE rotation (deg)" not in markdown_summary(result, "gt", "est")
