"""Our evaluation equals evo 1.38's on every reference trajectory in ../shared/data (to 1e-6)."""

import copy

import numpy as np
import pytest

evo_file = pytest.importorskip("evo.tools.file_interface")
from evo.core import metrics, sync  # noqa: E402
from evo.core.trajectory import PoseTrajectory3D  # noqa: E402

from evp.cli.evaluation import evaluate_files  # noqa: E402
from evp.config import EvalSettings  # noqa: E402
from evp.io.trajectory import write_trajectory  # noqa: E402
from evp.types import Trajectory  # noqa: E402
from tests.conftest import shared  # noqa: E402

TOL = 1e-6
STATS = ("rmse", "mean", "median", "std", "min", "max", "sse")

CASES = [
    ("tum_fr1_xyz/groundtruth.txt", "tum_fr1_xyz/est_rgbdslam.txt", "none", None),
    ("tum_fr1_xyz/groundtruth.txt", "tum_fr1_xyz/est_rgbdslam.txt", "se3", None),
    ("tum_fr1_xyz/groundtruth.txt", "tum_fr1_xyz/est_rgbdslam_drift.txt", "sim3", None),
    ("tum_fr1_xyz/groundtruth.txt", "tum_fr1_xyz/est_rgbdslam_drift_short.txt", "se3", None),
    ("tum_fr1_xyz/groundtruth.txt", "tum_fr1_xyz/est_orbslam_kf_mono.txt", "sim3", None),
    ("tum_fr1_xyz/groundtruth.txt", "tum_fr1_xyz/est_orbslam_kf_mono.txt", "sim3", 10),
    ("tum_fr2_desk/groundtruth.txt", "tum_fr2_desk/est_orbslam.txt", "se3", None),
    ("tum_fr2_desk/groundtruth.txt", "tum_fr2_desk/est_orbslam_kf_mono.txt", "sim3", None),
    ("euroc_v1_02/groundtruth_euroc.csv", "euroc_v1_02/est_tum.txt", "se3", None),
    ("euroc_v1_02/groundtruth_euroc.csv", "euroc_v1_02/est_tum.txt", "sim3", 200),
    ("euroc_v1_01/groundtruth_body_20hz_tum.txt", "euroc_v1_01/est_openvins_tum.txt", "se3", None),
    ("euroc_v1_01/groundtruth_body_20hz_tum.txt", "euroc_v1_01/est_openvins_tum.txt", "sim3", None),
    ("kitti_00/gt_poses.txt", "kitti_00/est_orbslam2_stereo.txt", "none", None),
    ("kitti_00/gt_poses.txt", "kitti_00/est_sptam.txt", "se3", None),
    ("kitti_odometry_gt_poses/09.txt", "kitti_odometry_example_estimates/example_1/09.txt", "sim3", None),
    ("kitti_odometry_gt_poses/10.txt", "kitti_odometry_example_estimates/example_1/10.txt", "se3", 100),
]


def _evo_read(path):
    text = path.read_text().lstrip()
    if path.suffix == ".csv":
        return evo_file.read_euroc_csv_trajectory(str(path))
    if len(text.splitlines()[0].split()) == 12:
        return evo_file.read_kitti_poses_file(str(path))
    return evo_file.read_tum_trajectory_file(str(path))


def _evo_results(ref_path, est_path, align, n_align, rpe_delta, rpe_unit):
    ref, est = _evo_read(ref_path), _evo_read(est_path)
    if isinstance(ref, PoseTrajectory3D) and isinstance(est, PoseTrajectory3D):
        ref, est = sync.associate_trajectories(ref, est)
    est = copy.deepcopy(est)
    if align != "none":
        est.align(ref, correct_scale=align == "sim3", n=-1 if n_align is None else n_align)
    out = {}
    for name, metric in (
        ("ape_t", metrics.APE(metrics.PoseRelation.translation_part)),
        ("ape_r", metrics.APE(metrics.PoseRelation.rotation_angle_deg)),
        ("rpe_t", metrics.RPE(metrics.PoseRelation.translation_part, rpe_delta, rpe_unit)),
        ("rpe_r", metrics.RPE(metrics.PoseRelation.rotation_angle_deg, rpe_delta, rpe_unit)),
    ):
        metric.process_data((ref, est))
        out[name] = metric.get_all_statistics()
    return out


def _assert_close(ours: dict, theirs: dict, label: str):
    for key in STATS:
        scale = max(1.0, abs(theirs[key])) if key == "sse" else 1.0
        assert abs(ours[key] - theirs[key]) <= TOL * scale, f"{label} {key}: ours {ours[key]!r} evo {theirs[key]!r}"


@pytest.mark.parametrize("ref, est, align, n_align", CASES)
@pytest.mark.parametrize("rpe_delta, rpe_unit", [(1, "frames"), (10, "frames"), (0.2, "m")])
def test_matches_evo(ref, est, align, n_align, rpe_delta, rpe_unit):
    root = shared("reference_trajectories")
    evo_unit = metrics.Unit.frames if rpe_unit == "frames" else metrics.Unit.meters
    theirs = _evo_results(root / ref, root / est, align, n_align, rpe_delta, evo_unit)
    result = evaluate_files(root / ref, root / est, EvalSettings(align=align, n_align=n_align, max_time_diff_s=0.01, rpe_delta=rpe_delta, rpe_unit=rpe_unit))
    summary = result.summary()
    _assert_close(summary["ape_translation_m"], theirs["ape_t"], "APE translation")
    _assert_close(summary["ape_rotation_deg"], theirs["ape_r"], "APE rotation")
    _assert_close(summary["rpe"]["translation_m"], theirs["rpe_t"], "RPE translation")
    _assert_close(summary["rpe"]["rotation_deg"], theirs["rpe_r"], "RPE rotation")
    assert summary["matched_poses"] == len(result.ref)


def test_georeferenced_utm_precision(tmp_path):
    """Large absolute coordinates (UTM) must not cost precision in association or alignment."""
    from scipy.spatial.transform import Rotation

    from evp.io.trajectory import read_trajectory

    path = shared("reference_trajectories/misc/georeferenced_utm.tum")
    ref = read_trajectory(path)
    rng = np.random.default_rng(3)
    R = Rotation.from_euler("z", 30, degrees=True).as_matrix()
    positions = 0.5 * (ref.positions - ref.positions[0]) @ R.T + [10, -20, 3] + rng.normal(0, 0.05, ref.positions.shape)
    est = Trajectory(positions, ref.quats_xyzw, ref.timestamps + 0.003, "est")
    write_trajectory(tmp_path / "est.tum", est)
    theirs = _evo_results(path, tmp_path / "est.tum", "sim3", None, 1, metrics.Unit.frames)
    ours = evaluate_files(path, tmp_path / "est.tum", EvalSettings(align="sim3", max_time_diff_s=0.01)).summary()
    _assert_close(ours["ape_translation_m"], theirs["ape_t"], "APE translation")
    assert ours["ape_translation_m"]["rmse"] < 0.2
