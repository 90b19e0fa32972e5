"""``evp align``: the visual track aligned to GPS, its error against GPS, and the GPS check (seed 002)."""

from __future__ import annotations

import json
from pathlib import Path

import typer

from evp.errors import DatasetError, UsageError
from evp.io.output_paths import writable_file, writable_folder

app = typer.Typer()


@app.command()
def align(
    flight: Path = typer.Argument(..., help="Dataset with images (or --trajectory), GPS and ideally a barometer."),
    out: Path | None = typer.Option(None, "--out", help="Folder for the geo-referenced track, statistics and plots."),
    json_out: Path | None = typer.Option(None, "--json", help="Write the horizontal error statistics as JSON."),
    align_fraction: float | None = typer.Option(None, "--align-fraction", help="Align on this first fraction of the GPS fixes (else the configured window)."),
    trajectory: Path | None = typer.Option(None, "--trajectory", help="Visual track (TUM, e.g. from evp run) instead of running the estimator."),
    mode: str | None = typer.Option(None, "--mode", help="2d+baro or 3d+baro."),
    track: str | None = typer.Option(
        None,
        "--track",
        help="refined (default: the estimator's end-of-run adjusted trajectory, as evp run writes it) or live (frame by frame: faster, weaker).",
    ),
    config: Path | None = typer.Option(None, "--config", help="Settings YAML (align, gps_monitor, vo sections)."),
    fmt: str | None = typer.Option(None, "--format", help="Reader name, to skip auto-detection."),
    camera: str | None = typer.Option(
        None, "--camera", help="Calibration file (OpenCV, ROS, ORB-SLAM, Kalibr, EuRoC, calib.txt) or profile name (evp camera list), instead of the dataset's."
    ),
) -> None:
    """Align the visual track to GPS (seed 002), report the error against GPS after the alignment
    phase, and check GPS for spoofing and jamming."""
    from pydantic import ValidationError

    from evp.cli.dataset import echo_warnings
    from evp.cli.progress import progress_of
    from evp.config import AlignmentSettings, load_settings, write_settings
    from evp.eval.flight_report import flight_summary, write_flight_report
    from evp.fusion.flight import process_flight
    from evp.fusion.gps_input import AlignmentError
    from evp.io.registry import open_dataset
    from evp.io.trajectory import read_trajectory
    from evp.pipeline import run_dataset
    from evp.run_setup import camera_for, make_estimator, resolve_settings, with_camera

    writable_folder(out)
    writable_file(json_out, "--json", "metrics.json")
    if align_fraction is not None and not 0 < align_fraction < 1:  # said before minutes of estimation, not after
        raise UsageError(f"--align-fraction {align_fraction:g}: give a fraction between 0 and 1 (0.33: the first third of the GPS fixes)")
    settings = with_camera(load_settings(config), camera)
    if mode:
        try:
            settings = settings.model_copy(update={"align": AlignmentSettings(**{**settings.align.model_dump(), "mode": mode})})
        except ValidationError:
            raise UsageError(f"--mode must be 2d+baro or 3d+baro, not {mode!r}") from None
    if track is not None:
        if track not in ("refined", "live"):
            raise UsageError(f"--track must be refined or live, not {track!r}")
        settings = settings.model_copy(update={"align": settings.align.model_copy(update={"visual_track": track})})
    dataset = open_dataset(flight, fmt)
    echo_warnings(dataset)
    settings = resolve_settings(settings, dataset)  # settings.yaml then names what ran
    if not dataset.gps:  # said before the estimation, not after it
        raise AlignmentError(f"{dataset.root}: the dataset has no GPS fixes to align to")
    if trajectory is not None:
        odometry = read_trajectory(trajectory)
        track = f"the trajectory file {trajectory}"
    else:
        if dataset.num_frames == 0:
            raise DatasetError(flight, "no images to estimate a visual track from; give --trajectory")
        estimator = make_estimator(camera_for(dataset, settings), settings, dataset)
        with progress_of(f"{settings.estimator} {dataset.name}", dataset.num_frames) as progress:
            run = run_dataset(dataset, estimator, progress.advance)
        odometry, track = visual_track(run, settings.estimator, settings.align.visual_track, dataset.name)
    typer.echo(f"visual track: {track}")
    result = process_flight(dataset.gps, dataset.baro, odometry, settings.align, settings.gps_monitor, align_fraction)
    if out is not None:
        summary = write_flight_report(result, out)
        write_settings(settings, out)
    else:
        summary = flight_summary(result)
    summary["visual_track"] = track
    a = summary["alignment"]
    validation = (
        f"validation RMSE {a['validation_rmse_m']:.2f} m"
        if a["validation_rmse_m"] is not None
        else "not validated: too few pairs to hold some out, fitted on all with the default settings"
    )
    typer.echo(f"aligned on {a['pairs_used']} pairs ({a['mode']}, {a['model']}, clock offset {a['clock_offset_s']:+.2f} s, {validation})")
    typer.echo(
        f"horizontal error vs GPS over {summary['n_evaluated']} later fixes: mean {summary['mean']:.2f} m, max {summary['max']:.2f} m, "
        f"Q1 {summary['q1']:.2f}, Q3 {summary['q3']:.2f}, IQR {summary['iqr']:.2f}, std {summary['std']:.2f}"
    )
    for event in summary["events"]:
        typer.echo(f"event at {event['t']:.1f} s: {event['kind']}: {event['message']}")
    for warning in summary["warnings"]:
        typer.echo(f"warning: {warning}", err=True)
    if json_out:
        json_out.parent.mkdir(parents=True, exist_ok=True)
        json_out.write_text(json.dumps(summary, indent=2))


def visual_track(run, estimator: str, choice: str, name: str):
    """The visual track to align and what it is: the estimator's refined trajectory (one frame and
    scale for the whole flight) unless ``choice`` is live or the estimator offers none; else the
    live poses in segments between tracking losses (each its own frame)."""
    from evp.cli.progress import status_of

    if choice == "refined":
        with status_of(f"{name}: refining the trajectory (end of run)"):
            run.final_trajectory()
        if run.refined is not None and len(run.refined) >= 2:
            return run.refined, f"the {estimator} estimator's refined trajectory ({len(run.refined)} poses, as evp run writes it)"
    segments = run.segments()
    why = "" if choice == "live" else f"; {estimator} offers no refined trajectory"
    return segments, f"the {estimator} estimator's live poses ({sum(len(s) for s in segments)} in {len(segments)} segment(s){why})"
