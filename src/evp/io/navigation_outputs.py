"""The files and figures of a run whose poses the navigation stage made metric: the fused
trajectory's evaluation (SE3 alignment, no scale, beside Sim3; once georeferenced, with no
alignment at all), its scale against the truth's, and navigation.csv (scale, biases, velocity and
the visual update per frame)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from evp.config import Settings
from evp.errors import EvaluationError
from evp.fusion.geodesy import EnuFrame
from evp.fusion.navigation_stage import NavigationStage
from evp.io.dataset import Dataset
from evp.pipeline import RunResult
from evp.types import Trajectory

WARNINGS_KEPT = 20  # the first warnings go into metrics.json; the count says how many there were
NAVIGATION_CSV_HEADER = (
    "timestamp,x,y,z,vx,vy,vz,scale,scale_sigma,scale_known,gyro_bias_x,gyro_bias_y,gyro_bias_z,"
    "accel_bias_x,accel_bias_y,accel_bias_z,baro_bias,visual_update,visual_nis\n"
)


def write_navigation_csv(stage: NavigationStage, path: Path) -> None:
    """One row per frame the filter answered."""
    with path.open("w") as handle:
        handle.write(NAVIGATION_CSV_HEADER)
        for record in stage.records:
            o, visual = record.output, record.visual
            numbers = [*o.T_world_body[:3, 3], *o.velocity, o.scale, o.scale_sigma, int(o.scale_known), *o.gyro_bias, *o.accel_bias, o.baro_bias]
            update = "none" if visual is None else visual.status.value
            nis = float("nan") if visual is None else visual.nis
            handle.write(f"{float(o.timestamp)!r}," + ",".join(f"{v:.9g}" for v in numbers) + f",{update},{nis:.6g}\n")


def georeferenced_trajectory(result: RunResult) -> Trajectory:
    """The tracked poses the stage answered in ENU at the take-off point."""
    poses = [e for e in result.tracked if e.georeferenced]
    return Trajectory.from_poses(np.array([e.T_world_cam for e in poses]).reshape(-1, 4, 4), np.array([e.timestamp for e in poses]), "georeferenced")


def truth_in_enu(dataset: Dataset, frame: EnuFrame) -> Trajectory:
    """The ground truth (ENU at ``dataset.enu_origin``) in ENU at ``frame`` (the run's take-off
    point). Positions go through WGS-84; the rotations are kept: the two tangent frames turn by the
    angle the origins subtend at the Earth's centre, 1.6e-5 rad per 100 m."""
    truth = dataset.ground_truth
    geodetic = EnuFrame(*dataset.enu_origin).to_geodetic(truth.positions)
    return Trajectory(frame.to_enu(*geodetic.T), truth.quats_xyzw, truth.timestamps, truth.name)


def _unaligned_figures(stage: NavigationStage, result: RunResult, dataset: Dataset, settings: Settings) -> dict:
    """The georeferenced poses against the truth with no alignment: horizontal error (m)."""
    from evp.eval.evaluate import evaluate

    georeferenced = georeferenced_trajectory(result)
    if stage.enu_frame is None or dataset.enu_origin is None or len(georeferenced) < 3:
        return {}
    none = evaluate(truth_in_enu(dataset, stage.enu_frame), georeferenced, settings.eval.model_copy(update={"align": "none"}))
    horizontal = none.ape_translation_xy
    return {
        "horizontal_error_mean_m": float(horizontal.mean()),
        "horizontal_error_max_m": float(horizontal.max()),
        "horizontal_error_rmse_m": float(np.sqrt(np.mean(horizontal**2))),
        "ate_none_rmse_m": none.summary()["rmse"],
        "georeferenced_poses": len(none.ref),
    }


def navigation_metrics(stage: NavigationStage, result: RunResult, dataset: Dataset, settings: Settings, out: Path) -> dict:
    """metrics.json's ``navigation`` section; with ground truth the fused trajectory's ATE after
    SE3 alignment (no scale: the figure a metric trajectory must meet) and after Sim3, its plots
    in plots/navigation/, and the scale's error against the Sim3 scale of SLAM's live poses (the
    poses the filter fused) to the truth."""
    metric = result.metric_trajectory()
    statuses = [r.visual.status.value for r in stage.records if r.visual is not None]
    section: dict = {
        "status": stage.status,
        "initialised_at_s": stage.initialised_at,
        "initial_scale": None if stage.alignment is None else stage.alignment.scale,
        "metric_frames": len(metric),
        "sensors_used": sorted(stage.sensors_used),
        "visual_updates": {status: statuses.count(status) for status in sorted(set(statuses))},
        "warnings_count": len(stage.warnings),
        "warnings": stage.warnings[:WARNINGS_KEPT],
    }
    if stage.records:
        last = stage.records[-1].output
        section.update(scale=last.scale, scale_sigma=last.scale_sigma, scale_known=last.scale_known, georeferenced=last.georeferenced)
    if stage.enu_frame is not None:
        f = stage.enu_frame
        section["take_off_point"] = {"latitude_deg": f.latitude_deg, "longitude_deg": f.longitude_deg, "altitude_m": f.altitude_m}
        section["gps_trusted"] = stage.gps_trusted
        section["gps_events"] = [{"timestamp": e.timestamp, "kind": e.kind, "message": e.message} for e in stage.gps_monitor.events]
    if dataset.ground_truth is None or len(metric) < 3:
        return section
    from evp.eval.evaluate import evaluate
    from evp.eval.report import write_report

    try:
        se3 = evaluate(dataset.ground_truth, metric, settings.eval.model_copy(update={"align": "se3"}))
        sim3 = evaluate(dataset.ground_truth, metric, settings.eval.model_copy(update={"align": "sim3"}))
        visual = evaluate(dataset.ground_truth, result.trajectory(), settings.eval.model_copy(update={"align": "sim3"}))
    except EvaluationError as exc:
        section["evaluation_error"] = str(exc)
        return section
    section.update(ate_se3_rmse_m=se3.summary()["rmse"], ate_sim3_rmse_m=sim3.summary()["rmse"], matched_poses=len(se3.ref))
    section.update(_unaligned_figures(stage, result, dataset, settings))
    section["reference_scale"] = visual.alignment.scale
    scales = np.array([r.output.scale for r in stage.records])
    errors = scales / visual.alignment.scale - 1.0
    section["scale_error"] = float(errors[-1])
    section["scale_error_max_abs"] = float(np.max(np.abs(errors)))
    write_report(se3, out / "plots" / "navigation", "ground truth", "trajectory.tum (SE3-aligned)")
    return section


def live_navigation_metrics(result: RunResult, dataset: Dataset, settings: Settings) -> dict:
    """The SE3 ATE of the fused poses as answered live (``live_ate_se3_rmse_m``), beside a
    section computed on the refined pass; empty without ground truth."""
    live = result.metric_trajectory()
    if dataset.ground_truth is None or len(live) < 3:
        return {}
    from evp.eval.evaluate import evaluate

    try:
        se3 = evaluate(dataset.ground_truth, live, settings.eval.model_copy(update={"align": "se3"}))
    except EvaluationError as exc:
        return {"live_evaluation_error": str(exc)}
    return {"live_ate_se3_rmse_m": se3.summary()["rmse"], "live_metric_frames": len(live)}
