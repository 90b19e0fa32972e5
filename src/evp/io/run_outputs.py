"""The files an offline run leaves: trajectories, map, states, timing, metrics, plots, settings."""

from __future__ import annotations

import json
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from evp.config import Settings, write_settings
from evp.errors import EvaluationError
from evp.fusion.map_georeference import MapGeoreference
from evp.fusion.navigation_stage import NavigationStage
from evp.io.dataset import Dataset
from evp.io.navigation_outputs import live_navigation_metrics, navigation_metrics, write_navigation_csv
from evp.io.trajectory import write_trajectory
from evp.pipeline import RunResult
from evp.types import Trajectory

if TYPE_CHECKING:
    from evp.slam.map import Map


def _stats(values: list[float]) -> dict:
    array = np.array(values) if values else np.zeros(1)
    return {"median": float(np.median(array)), "p95": float(np.percentile(array, 95))}


def run_timing(result: RunResult) -> dict:
    """timing.json: the estimator's tracking time per frame (its own figure when it times tracking
    apart from background work, as SLAM does without its inline mapping; else the pipeline's),
    medians, OpenCV ORB's time on the same frames and the ratio, the thread CPU time of the
    estimator's feed per frame and of the ORB (``feed_cpu_ms``, ``opencv_orb_cpu_ms``: less
    sensitive to a loaded machine than the wall clock) and the estimator's own figures."""
    own = result.estimator.timing()
    tracking = own.get("tracking_ms", result.tracking_ms)
    tracking_stats = _stats(tracking)
    timing: dict = {"tracking_ms": tracking, "tracking_ms_median": tracking_stats["median"], "tracking_ms_p95": tracking_stats["p95"]}
    if result.reference_orb_ms:
        timing["opencv_orb_ms"] = result.reference_orb_ms
        timing["opencv_orb_ms_median"] = _stats(result.reference_orb_ms)["median"]
        timing["tracking_to_orb_ratio"] = timing["tracking_ms_median"] / max(timing["opencv_orb_ms_median"], 1e-9)
    if result.feed_cpu_ms:
        timing["feed_cpu_ms"] = result.feed_cpu_ms
        timing["feed_cpu_ms_median"] = _stats(result.feed_cpu_ms)["median"]
        if result.reference_orb_cpu_ms:
            timing["opencv_orb_cpu_ms_median"] = _stats(result.reference_orb_cpu_ms)["median"]
            timing["feed_to_orb_cpu_ratio"] = timing["feed_cpu_ms_median"] / max(timing["opencv_orb_cpu_ms_median"], 1e-9)
    for name, value in own.items():
        if name == "tracking_ms":
            continue
        timing[name] = value
        if name == "mapping_ms_per_keyframe":
            timing["mapping_ms_median"] = _stats(value)["median"]
    return timing


def run_map_georeference(estimator, sparse_map: Map, result: RunResult, stage: NavigationStage | None, settings: Settings) -> MapGeoreference | None:
    """The georeference map.npz keeps: fitted to this run's own keyframes where the navigation
    stage was georeferenced with GPS trusted (:func:`~evp.fusion.map_georeference.georeference_from_run`);
    else, for a run that stayed in the saved map it started from, that map's (the frame is the
    same); else None."""
    from evp.fusion.map_georeference import georeference_from_run
    from evp.io.map_files import read_map_georeference  # map_files imports the SLAM map: only runs that have one

    if stage is not None and stage.enu_frame is not None:
        first_own = getattr(estimator, "first_own_keyframe", 0)
        keyframes = [(kf.timestamp, kf.centre) for kf in sparse_map.keyframes.values() if kf.id >= first_own]
        frame = stage.enu_frame
        origin = (frame.latitude_deg, frame.longitude_deg, frame.altitude_m)
        fitted = georeference_from_run(keyframes, result.estimates, origin, settings.navigation.gps_default_sigma_m)
        if fitted is not None:
            return fitted
    if getattr(estimator, "in_saved_map", False):
        return read_map_georeference(Path(settings.slam.map))
    return None


def write_outputs(
    result: RunResult,
    dataset: Dataset,
    settings: Settings,
    out: Path,
    navigation: NavigationStage | None = None,
    refined_navigation: tuple[RunResult, NavigationStage] | None = None,
) -> dict:
    """trajectory.tum, states.csv, timing.json, metrics.json (+ plots: the evaluation's when ground
    truth exists, else plots/trajectory.png), settings.yaml; trajectory_live.tum (the poses as answered live) when the estimator's trajectory
    is a refined one; camera_estimated.yaml (usable as camera.calibration_file) when the
    estimator estimated the lens; for an estimator with a map also keyframes.tum, map.ply and map.npz.

    With a ``navigation`` stage, trajectory.tum is the fused metric, gravity-aligned trajectory
    (the estimator's while the stage never initialised), the estimator's own goes to
    trajectory_visual.tum, navigation.csv follows the filter, and metrics.json gains a
    ``navigation`` section, ``ate_se3_rmse`` and, once georeferenced, ``horizontal_error_none_mean``
    (no alignment; :func:`navigation_metrics`); the top-level ATE
    figures stay the estimator's trajectory's, as without the stage. With ``refined_navigation``
    (the stage run again on the refined trajectory: :func:`evp.run_setup.navigation_on_refined`)
    that pass gives trajectory.tum, navigation.csv and the section, trajectory_live.tum holds the
    fused poses as answered live and the section their SE3 ATE as ``live_ate_se3_rmse_m``."""
    estimator = result.estimator
    out.mkdir(parents=True, exist_ok=True)
    write_settings(settings, out)
    trajectory = result.final_trajectory()
    fused_result, fused_stage = refined_navigation or (result, navigation)
    metric = fused_result.metric_trajectory() if fused_stage is not None else None
    if metric is not None:
        write_trajectory(out / "trajectory_visual.tum", trajectory)
        write_navigation_csv(fused_stage, out / "navigation.csv")
    write_trajectory(out / "trajectory.tum", metric if metric else trajectory)
    live_fused = result.metric_trajectory() if refined_navigation is not None else None
    if live_fused:
        write_trajectory(out / "trajectory_live.tum", live_fused)
    elif result.refined is not None:
        write_trajectory(out / "trajectory_live.tum", result.trajectory())
    if estimator.lens is not None:
        from evp.calib.camera_files import write_opencv_yaml

        write_opencv_yaml(out / "camera_estimated.yaml", estimator.lens, text={"estimated_by": type(estimator).__name__})
    keyframes = estimator.keyframe_trajectory()
    if keyframes is not None:
        write_trajectory(out / "keyframes.tum", Trajectory.from_poses(keyframes[1], keyframes[0], "keyframes"))
    sparse_map = estimator.sparse_map()
    if sparse_map is not None:
        from evp.io.map_files import save_map, write_map_ply

        write_map_ply(sparse_map, out / "map.ply")
        save_map(sparse_map, out / "map.npz", run_map_georeference(estimator, sparse_map, fused_result, fused_stage, settings))
    with (out / "states.csv").open("w") as handle:
        handle.write("timestamp,state,quality\n")
        for e in result.estimates:
            handle.write(f"{e.timestamp!r},{e.tracking_state.value},{e.quality}\n")
    (out / "timing.json").write_text(json.dumps(run_timing(result), indent=2))
    metrics: dict = {
        "frames": dataset.num_frames,
        "frames_fed": len(result.estimates),
        "frames_dropped": len(result.dropped),
        "tracked_frames": len(trajectory),
        "tracked_fraction": len(trajectory) / max(1, dataset.num_frames),
        "tracked_live_frames": len(result.tracked),  # answered with a pose as they came (SLAM's start back-filled later is not)
        "init_frame": result.init_frame,
        "skipped": result.skipped,
        **estimator.report(),
    }
    if dataset.ground_truth is not None and len(trajectory) >= 3:
        from evp.eval.evaluate import evaluate
        from evp.eval.report import write_report

        try:
            evaluation = evaluate(dataset.ground_truth, trajectory, settings.eval)  # settings resolved for the dataset (resolve_settings)
        except EvaluationError as exc:
            metrics["evaluation_error"] = str(exc)
        else:
            metrics.update(evaluation.summary())
            write_report(evaluation, out / "plots", "ground truth", "trajectory.tum")
    elif dataset.ground_truth is None and len(trajectory) >= 2:  # nothing to compare with: the track itself is the figure
        from evp.eval.plots import plot_trajectory

        (out / "plots").mkdir(exist_ok=True)
        plot_trajectory(metric if metric else trajectory, out / "plots" / "trajectory.png", metric is not None, settings.eval.plane)
    if fused_stage is not None:
        metrics["navigation"] = navigation_metrics(fused_stage, fused_result, dataset, settings, out)
        if live_fused:
            metrics["navigation"].update(live_navigation_metrics(result, dataset, settings))
        if "ate_se3_rmse_m" in metrics["navigation"]:
            metrics["ate_se3_rmse"] = metrics["navigation"]["ate_se3_rmse_m"]
        if "horizontal_error_mean_m" in metrics["navigation"]:
            metrics["horizontal_error_none_mean"] = metrics["navigation"]["horizontal_error_mean_m"]
    (out / "metrics.json").write_text(json.dumps(metrics, indent=2))
    return metrics
