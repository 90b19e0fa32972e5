import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from evp.config import EvalSettings
from evp.errors import EvaluationError
from evp.eval.association import associate
from evp.eval.evaluate import evaluate
from evp.eval.metrics import Alignment, DeltaUnit, rpe_pairs
from evp.eval.statistics import error_statistics
from evp.geometry.alignment import Similarity
from evp.types import Trajectory


def _helix(n=200):
    t = np.linspace(0, 20, n)
    positions = np.column_stack([np.cos(t), np.sin(t), 0.1 * t])
    quats = Rotation.from_euler("z", t[:, None]).as_quat()
    return Trajectory(positions, quats, t, "helix")


def _transformed(trajectory, similarity: Similarity, time_shift=0.0):
    poses = similarity.apply_to_poses(trajectory.poses)
    return Trajectory.from_poses(poses, trajectory.timestamps + time_shift, "est")


@pytest.mark.parametrize("mode", [Alignment.SE3, Alignment.SIM3])
def test_alignment_removes_an_exact_transform(mode):
    ref = _helix()
    scale = 1.0 if mode is Alignment.SE3 else 0.3
    est = _transformed(ref, Similarity(Rotation.from_euler("z", 40, degrees=True).as_matrix(), np.array([5.0, 1.0, -2.0]), scale))
    result = evaluate(ref, est, EvalSettings(align=mode.value, max_time_diff_s=0.01))
    assert result.summary()["rmse"] < 1e-9
    assert result.summary()["ape_rotation_deg"]["max"] < 1e-6
    assert result.alignment.scale == pytest.approx(1 / scale)


def test_no_alignment_reports_the_offset():
    ref = _helix()
    est = _transformed(ref, Similarity(np.eye(3), np.array([0.0, 0.3, 0.4])))
    summary = evaluate(ref, est, EvalSettings(align="none", max_time_diff_s=0.01)).summary()
    assert summary["rmse"] == pytest.approx(0.5)
    assert summary["xy_rmse"] == pytest.approx(0.3)
    assert summary["matched_poses"] == 200


def test_alignment_on_first_poses_only_exposes_later_drift():
    ref = _helix()
    positions = ref.positions.copy()
    positions[100:, 0] += np.linspace(0, 1.0, 100)  # drift after pose 100
    est = Trajectory(positions, ref.quats_xyzw, ref.timestamps)
    result = evaluate(ref, est, EvalSettings(align="se3", n_align=50, max_time_diff_s=0.01))
    assert result.ape_translation[:100].max() < 1e-9
    assert result.ape_translation[-1] == pytest.approx(1.0)


def test_association_applies_offset_and_max_difference():
    ref = _helix()
    est = Trajectory(ref.positions[::2], ref.quats_xyzw[::2], ref.timestamps[::2] - 0.55, "est")
    with pytest.raises(EvaluationError, match="no poses matched"):
        associate(ref, est, max_diff=0.01)
    with pytest.raises(EvaluationError, match="the estimate trajectory has no poses"):
        associate(ref, est.select(np.array([], int)))
    ref_m, est_m = associate(ref, est, max_diff=0.01, offset=0.55)
    assert len(ref_m) == 100
    assert np.allclose(ref_m.positions, est_m.positions)


def test_statistics_of_known_errors():
    stats = error_statistics(np.array([1.0, 2.0, 3.0, 4.0]))
    assert stats["rmse"] == pytest.approx(np.sqrt(7.5))
    assert stats["mean"] == 2.5 and stats["median"] == 2.5
    assert stats["min"] == 1.0 and stats["max"] == 4.0
    assert stats["q1"] == 1.75 and stats["q3"] == 3.25 and stats["iqr"] == 1.5
    assert stats["std"] == pytest.approx(np.std([1, 2, 3, 4]))
    with pytest.raises(EvaluationError):
        error_statistics(np.array([]))


def test_z_subset_selects_poses_near_target_altitude():
    ref = _helix()
    est = _transformed(ref, Similarity(np.eye(3), np.array([0.1, 0.0, 0.0])))
    summary = evaluate(ref, est, EvalSettings(align="none", max_time_diff_s=0.01, z_target_m=1.0, z_tolerance_m=0.5)).summary()
    expected = int(np.sum(np.abs(ref.positions[:, 2] - 1.0) < 0.5))
    assert summary["subset"]["poses"] == expected > 0
    assert summary["subset"]["ape_translation_m"]["mean"] == pytest.approx(0.1)


def test_rpe_pairs_by_frames_and_metres():
    poses = np.tile(np.eye(4), (11, 1, 1))
    poses[:, 0, 3] = np.arange(11) * 0.5
    assert rpe_pairs(poses, 5, DeltaUnit.FRAMES) == [(0, 5), (5, 10)]
    assert rpe_pairs(poses, 1.0, DeltaUnit.METERS) == [(0, 2), (2, 4), (4, 6), (6, 8), (8, 10)]
    with pytest.raises(EvaluationError):
        rpe_pairs(poses, 0, DeltaUnit.FRAMES)
