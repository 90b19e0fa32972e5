"""``evp info``, ``evp run`` and ``evp formats``: what a dataset holds, and the estimator run on it."""

from __future__ import annotations

import json
from pathlib import Path

import typer

from evp.errors import DatasetError, InitialisationError, UsageError
from evp.io.output_paths import writable_folder

app = typer.Typer()
ALIGNED = {"none": "unaligned", "se3": "SE3-aligned", "sim3": "Sim3-aligned"}


@app.command()
def info(
    path: Path = typer.Argument(..., help="Dataset folder or file (format auto-detected)."),
    fmt: str | None = typer.Option(None, "--format", help="Reader name, to skip auto-detection."),
    as_json: bool = typer.Option(False, "--json", help="Print JSON instead of text."),
    camera: str | None = typer.Option(
        None, "--camera", help="Calibration file (OpenCV, ROS, ORB-SLAM, Kalibr, EuRoC, calib.txt) or profile name (evp camera list), instead of the dataset's."
    ),
) -> None:
    """Print what a dataset holds: format, frames, rate, duration, sensors, calibration, ground truth."""
    from evp.calib.profiles import camera_from
    from evp.io.registry import open_dataset
    from evp.io.summary import describe, summarise
    from evp.run_setup import frame_size

    dataset = open_dataset(path, fmt)
    if camera is not None:
        dataset.camera = camera_from(camera, frame_size(dataset))
        dataset.notes.append(f"calibration: --camera {camera}")
    summary = summarise(dataset)
    typer.echo(json.dumps(summary, indent=2) if as_json else describe(summary))


@app.command()
def run(
    dataset_path: Path = typer.Argument(..., metavar="DATASET", help="Dataset folder or file (format auto-detected)."),
    out: Path = typer.Option(..., "--out", help="Folder for trajectory.tum, metrics.json, plots, settings."),
    config: Path | None = typer.Option(None, "--config", help="Settings YAML (EVP layout or ORB-SLAM settings)."),
    fmt: str | None = typer.Option(None, "--format", help="Reader name, to skip auto-detection."),
    realtime: bool = typer.Option(
        False,
        "--realtime",
        help="Replay at the recorded frame rate, always feeding the newest frame and dropping those that arrive while the estimator is busy, as the base station does live (default: every frame, as fast as possible).",
    ),
    speed: float = typer.Option(1.0, "--speed", min=0.01, help="With --realtime: play the recording this many times faster."),
    estimator_name: str | None = typer.Option(None, "--estimator", help="Override the settings' estimator: auto, slam, klt-vo, nadir or ekf-slam."),
    saved_map: Path | None = typer.Option(
        None,
        "--map",
        help="Start SLAM from a map an earlier run saved (its map.npz; sets slam.map): it relocalises there, and a georeferenced map georeferences this run at once.",
    ),
    camera: str | None = typer.Option(
        None, "--camera", help="Calibration file (OpenCV, ROS, ORB-SLAM, Kalibr, EuRoC, calib.txt) or profile name (evp camera list), instead of the dataset's."
    ),
) -> None:
    """Estimate the camera trajectory of a dataset and evaluate it when ground truth exists."""
    from evp.cli.progress import progress_of, status_of
    from evp.config import load_settings
    from evp.estimator import NOT_INITIALISED_HINT
    from evp.io.registry import open_dataset
    from evp.run_setup import estimate, navigation_off, refine_and_write, resolve_settings, with_camera

    writable_folder(out)
    settings = with_camera(load_settings(config), camera)
    if estimator_name is not None:
        settings = with_estimator(settings, estimator_name)
    if saved_map is not None:
        if not saved_map.is_file():
            raise UsageError(f"--map {saved_map}: no such file (give the map.npz an earlier evp run wrote)")
        settings = settings.model_copy(update={"slam": settings.slam.model_copy(update={"map": str(saved_map)})})
    dataset = open_dataset(dataset_path, fmt)
    if dataset.num_frames == 0:
        raise DatasetError(dataset_path, dataset.no_frames_reason())
    echo_warnings(dataset)
    settings = resolve_settings(settings, dataset)  # settings.yaml then names what ran
    if dataset.imu and (unfused := navigation_off(dataset, settings)) is not None:
        typer.echo(f"warning: the IMU is not fused: {unfused}", err=True)
    with progress_of(dataset.name, dataset.num_frames) as progress:
        result, navigation, estimator = estimate(dataset, settings, progress.advance, speed if realtime else None)
    with status_of(f"{dataset.name}: refining the trajectory (end of run)"):
        metrics = refine_and_write(result, navigation, estimator, dataset, settings, out)
    echo_saved_map(metrics.get("saved_map"))
    if metrics["tracked_frames"] == 0:
        frames = f"{dataset.num_frames} frame" + ("s" if dataset.num_frames != 1 else "")
        excursion = dataset.ground_truth_excursion()
        moved = "" if excursion is None else f" (its ground truth moves {excursion:.3g} m in that time)"
        raise InitialisationError(
            f"{dataset.name}: too short or too still to initialise: no frame tracked in {frames} ({dataset.frame_times[-1] - dataset.frame_times[0]:.2f} s){moved}; "
            f"{NOT_INITIALISED_HINT} (outputs in {out})"
        )
    typer.echo(
        f"{dataset.name}: tracked {metrics['tracked_frames']}/{metrics['frames']} frames "
        f"({100 * metrics['tracked_fraction']:.1f} %; {metrics['tracked_live_frames']} answered live, the first at frame {metrics['init_frame']})"
        + (f", {metrics['frames_dropped']} dropped by the real-time replay (x{speed:g})" if realtime else "")
    )
    if metrics.get("gyro_aided_tracking"):
        typer.echo("tracking held to the gyro (the dataset's IMU, through its camera extrinsic)")
    if "rmse" in metrics:
        typer.echo(
            f"ATE ({ALIGNED[settings.eval.align]} RMSE) {metrics['rmse']:.4f} m over {metrics['matched_poses']} poses; "
            f"ground-truth path {metrics['reference_path_length_m']:.2f} m"
        )
    if navigation is not None:
        echo_navigation(metrics["navigation"])
    for reason in metrics["skipped"]:
        typer.echo(f"skipped: {reason}", err=True)
    typer.echo(f"results in {out}")


def echo_saved_map(saved: dict | None) -> None:
    """What became of the saved map the run started from (``slam.map``), when it had one."""
    if saved is None:
        return
    if saved["fell_back_at"] is not None:
        typer.echo(
            f"warning: not relocalised in the saved map ({saved['keyframes']} keyframes); a new map was started at {saved['fell_back_at']:.3f} s", err=True
        )
    elif saved["relocalised_at"] is None:
        typer.echo(f"warning: never relocalised in the saved map ({saved['keyframes']} keyframes)", err=True)
    else:
        typer.echo(f"relocalised in the saved map ({saved['keyframes']} keyframes) at {saved['relocalised_at']:.3f} s")


def with_estimator(settings, name: str):
    """The settings with ``estimator`` set from the command line (the other settings keep whether
    they were given, which the defaults that depend on the dataset look at)."""
    from typing import get_args

    from evp.config import Settings

    choices = get_args(Settings.model_fields["estimator"].annotation)
    if name not in choices:
        raise UsageError(f"--estimator {name!r}: choose one of {', '.join(choices)}")
    return settings.model_copy(update={"estimator": name})


def echo_navigation(section: dict) -> None:
    """The navigation stage's answer: its state, scale and SE3 ATE, and how many warnings."""
    line = f"navigation: {section['status']}"
    if "scale" in section:
        line += f"; scale {section['scale']:.4g} m/unit (1 sigma {100 * section['scale_sigma']:.2f} %)"
    if "ate_se3_rmse_m" in section:
        line += f"; ATE (SE3-aligned, no scale, RMSE) {section['ate_se3_rmse_m']:.4f} m, scale error {100 * section['scale_error']:+.2f} %"
    if "live_ate_se3_rmse_m" in section:
        line += f" (as answered live: {section['live_ate_se3_rmse_m']:.4f} m)"
    typer.echo(line)
    for warning in section["warnings"]:
        typer.echo(f"warning: navigation: {warning}", err=True)
    if section["warnings_count"] > len(section["warnings"]):
        typer.echo(f"warning: navigation: {section['warnings_count'] - len(section['warnings'])} more warnings (metrics.json)", err=True)


def echo_warnings(dataset) -> None:
    """What the reader had to assume (nominal frame times...), on stderr before the work starts."""
    for warning in dataset.warnings:
        typer.echo(f"warning: {warning}", err=True)


@app.command()
def formats() -> None:
    """List the dataset formats EVP reads (names for --format; the trajectory-only reader last)."""
    from evp.io.registry import readers

    for reader in readers():
        typer.echo(f"{reader.name:14s} {reader.description}")
