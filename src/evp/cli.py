"""The ``evp`` command line. Heavy modules are imported inside each command, so ``evp --help`` is fast."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import typer

from evp import __version__
from evp.errors import EvpError

HELP = """EVP: where is the vehicle, from its phone camera.

Examples:

  evp info data/sample/davis_slider_depth        what a dataset holds

  evp run data/sample/davis_slider_depth --out runs/sample    trajectory + metrics + plots

  evp eval groundtruth.txt estimate.txt --align sim3 --json metrics.json --report report/

  evp calibrate board_images/ --pattern chessboard --cols 9 --rows 7 --square 0.025 --out camera.yaml

  evp convert poses.txt poses.tum --to tum --times times.txt

  evp config dump > settings.yaml
"""

app = typer.Typer(help=HELP, no_args_is_help=True, pretty_exceptions_enable=False, add_completion=False, rich_markup_mode=None)
config_app = typer.Typer(help="Settings: show the defaults.", no_args_is_help=True)
app.add_typer(config_app, name="config")
vocabulary_app = typer.Typer(help="Bag-of-words vocabularies for place recognition: build one, show one.", no_args_is_help=True)
app.add_typer(vocabulary_app, name="vocabulary")
_state = {"debug": False}


def _version(value: bool) -> None:
    if value:
        typer.echo(f"evp {__version__}")
        raise typer.Exit()


@app.callback()
def _root(
    version: bool = typer.Option(False, "--version", callback=_version, is_eager=True, help="Print the version and exit."),
    debug: bool = typer.Option(False, "--debug", help="Show full tracebacks for errors."),
) -> None:
    _state["debug"] = debug


@app.command()
def info(
    path: Path = typer.Argument(..., help="Dataset folder or file (format auto-detected)."),
    fmt: str | None = typer.Option(None, "--format", help="Reader name, to skip auto-detection."),
    as_json: bool = typer.Option(False, "--json", help="Print JSON instead of text."),
) -> None:
    """Print what a dataset holds: format, frames, rate, duration, sensors, calibration, ground truth."""
    from evp.io.registry import open_dataset
    from evp.io.summary import describe, summarise

    summary = summarise(open_dataset(path, fmt))
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
) -> None:
    """Estimate the camera trajectory of a dataset and evaluate it when ground truth exists."""
    from rich.console import Console
    from rich.progress import Progress

    from evp.config import load_settings
    from evp.io.registry import open_dataset
    from evp.pipeline import run_dataset, write_outputs
    from evp.run_setup import camera_for, make_estimator

    settings = load_settings(config)
    dataset = open_dataset(dataset_path, fmt)
    if dataset.num_frames == 0:
        raise EvpError(f"{dataset_path}: no camera frames to run on ({dataset.format})")
    estimator = make_estimator(camera_for(dataset, settings), settings, dataset)
    with Progress(transient=True) as progress:
        task = progress.add_task(f"{dataset.name}", total=dataset.num_frames)
        # a real-time replay has no spare time to also run OpenCV's ORB on each frame
        reference_orb = None if realtime else settings.orb.n_features
        result = run_dataset(dataset, estimator, lambda n: progress.advance(task, n), reference_orb, speed if realtime else None)
    if result.refiner is not None:  # a survey adjustment or a global bundle adjustment: seconds after the last frame
        with Console(stderr=True).status(f"{dataset.name}: refining the trajectory (end of run)"):
            result.final_trajectory()  # estimators keep what this costs; write_outputs asks again
    metrics = write_outputs(result, dataset, settings, out)
    typer.echo(
        f"{dataset.name}: tracked {metrics['tracked_frames']}/{metrics['frames']} frames "
        f"({100 * metrics['tracked_fraction']:.1f} %; {metrics['tracked_live_frames']} answered live, the first at frame {metrics['init_frame']})"
        + (f", {metrics['frames_dropped']} dropped by the real-time replay (x{speed:g})" if realtime else "")
    )
    if "rmse" in metrics:
        typer.echo(
            f"ATE (Sim3-aligned RMSE) {metrics['rmse']:.4f} m over {metrics['matched_poses']} poses; "
            f"ground-truth path {metrics['reference_path_length_m']:.2f} m"
        )
    for reason in metrics["skipped"]:
        typer.echo(f"skipped: {reason}", err=True)
    typer.echo(f"results in {out}")


@app.command()
def sim(
    scenario: str | None = typer.Argument(None, help="Scenario name (see --list)."),
    out: Path | None = typer.Option(None, "--out", help="Folder to write the dataset to."),
    list_scenarios: bool = typer.Option(False, "--list", help="Print the scenario names, one per line."),
    duration: float | None = typer.Option(None, "--duration", help="Seconds (default: the scenario's)."),
    seed: int = typer.Option(0, "--seed", help="Random seed (noise, textures, paths)."),
    fps: float = typer.Option(30.0, "--fps", help="Camera frame rate."),
    camera: str | None = typer.Option(None, "--camera", help="nexus5x_640x380, global_752x480 or phone_1280x720."),
    texture: str | None = typer.Option(None, "--texture", help="rich, low, floor, wall, or image file(s) separated by commas."),
    altitude: float | None = typer.Option(None, "--altitude", help="Flight altitude / camera height (m)."),
    speed: float | None = typer.Option(None, "--speed", help="Cruise speed (m/s)."),
    pattern: str | None = typer.Option(None, "--pattern", help="Drone path: lawnmower, loops or free."),
    gimbal: bool = typer.Option(False, "--gimbal", help="Camera held level by a gimbal."),
    relief: bool = typer.Option(True, "--relief/--flat", help="Buildings and trees on the ground."),
    rolling_shutter: float = typer.Option(0.0, "--rolling-shutter", help="Row readout time (s); 0 = global shutter."),
    drop: float = typer.Option(0.0, "--drop", help="Probability of dropping a frame."),
    noise: float = typer.Option(2.0, "--noise", help="Image read noise (grey levels)."),
    image_format: str = typer.Option("jpg", "--image-format", help="jpg (quality 95, as a phone streams) or png (lossless)."),
    gps_offset: float = typer.Option(0.0, "--gps-clock-offset", help="GPS clock minus camera clock (s)."),
    spoof_start: float | None = typer.Option(None, "--spoof-start", help="Seconds into the run when GPS spoofing starts."),
    spoof_mode: str = typer.Option("pull", "--spoof-mode", help="pull (gradual) or jump."),
    spoof_rate: float = typer.Option(5.0, "--spoof-rate", help="Pull-off speed (m/s)."),
    spoof_jump: float = typer.Option(50.0, "--spoof-jump", help="Jump size (m)."),
    outage: list[str] = typer.Option([], "--gps-outage", help="Jamming window START:DURATION in seconds (repeatable)."),
    config: Path | None = typer.Option(None, "--config", help="YAML with any SimOptions field (sensor noise models...)."),
    workers: int = typer.Option(2, "--workers", min=1, help="Processes rendering images."),
) -> None:
    """Generate a synthetic dataset with exact ground truth (EuRoC-like folder, see docs/simulator.md)."""
    from evp.sim.scenarios import SCENARIOS

    if list_scenarios:
        typer.echo("\n".join(SCENARIOS))
        return
    if scenario is None or out is None:
        raise EvpError("give a scenario and --out DIR (or --list)")
    from rich.progress import Progress

    from evp.sim.cli_support import options_from_cli
    from evp.sim.generate import generate

    options = options_from_cli(
        config,
        duration=duration,
        seed=seed,
        fps=fps,
        camera=camera,
        texture=texture,
        altitude_m=altitude,
        speed_m_s=speed,
        pattern=pattern,
        gimbal=gimbal,
        relief=relief,
        rolling_shutter_s=rolling_shutter,
        drop_probability=drop,
        noise_sigma=noise,
        image_format=image_format,
        gps_clock_offset_s=gps_offset,
        spoof_start_s=spoof_start,
        spoof_mode=spoof_mode,
        spoof_rate_m_s=spoof_rate,
        spoof_jump_m=spoof_jump,
        outages=outage,
    )
    with Progress(transient=True) as progress:
        task = progress.add_task(f"{scenario}", total=None)
        result = generate(scenario, options, out, workers, lambda n: progress.advance(task, n), lambda total: progress.update(task, total=total))
    typer.echo(
        f"{scenario}: {result.frames} frames ({len(result.dropped)} dropped), {result.scenario.motion.duration:.1f} s, sensors {', '.join(result.scenario.sensors)} -> {out}"
    )


@app.command()
def align(
    flight: Path = typer.Argument(..., help="Dataset with images (or --trajectory), GPS and ideally a barometer."),
    out: Path | None = typer.Option(None, "--out", help="Folder for the geo-referenced track, statistics and plots."),
    json_out: Path | None = typer.Option(None, "--json", help="Write the horizontal error statistics as JSON."),
    align_fraction: float | None = typer.Option(None, "--align-fraction", help="Align on this first fraction of the GPS fixes (else the configured window)."),
    trajectory: Path | None = typer.Option(None, "--trajectory", help="Visual track (TUM, e.g. from evp run) instead of running the estimator."),
    mode: str | None = typer.Option(None, "--mode", help="2d+baro or 3d+baro."),
    config: Path | None = typer.Option(None, "--config", help="Settings YAML (align, gps_monitor, vo sections)."),
) -> None:
    """Align the visual track to GPS (seed 002), report the error against GPS after the alignment
    phase, and check GPS for spoofing and jamming."""
    from rich.progress import Progress

    from evp.config import load_settings, write_settings
    from evp.eval.flight_report import flight_summary, write_flight_report
    from evp.fusion.flight import process_flight
    from evp.fusion.gps_input import AlignmentError
    from evp.io.registry import open_dataset
    from evp.io.trajectory import read_trajectory
    from evp.pipeline import run_dataset
    from evp.run_setup import camera_for, make_estimator

    settings = load_settings(config)
    if mode:
        from pydantic import ValidationError

        from evp.config import AlignmentSettings

        try:
            settings = settings.model_copy(update={"align": AlignmentSettings(**{**settings.align.model_dump(), "mode": mode})})
        except ValidationError:
            raise EvpError(f"--mode must be 2d+baro or 3d+baro, not {mode!r}") from None
    dataset = open_dataset(flight)
    if trajectory is not None:
        odometry = read_trajectory(trajectory)
    else:
        if dataset.num_frames == 0:
            raise EvpError(f"{flight}: no images to estimate a visual track from; give --trajectory")
        estimator = make_estimator(camera_for(dataset, settings), settings, dataset)
        with Progress(transient=True) as progress:
            task = progress.add_task(f"visual odometry {dataset.name}", total=dataset.num_frames)
            odometry = run_dataset(dataset, estimator, lambda n: progress.advance(task, n)).segments()
    if not dataset.gps:
        raise AlignmentError(f"{dataset.root}: the dataset has no GPS fixes to align to")
    result = process_flight(dataset.gps, dataset.baro, odometry, settings.align, settings.gps_monitor, align_fraction)
    if out is not None:
        summary = write_flight_report(result, out)
        write_settings(settings, out)
    else:
        summary = flight_summary(result)
    a = summary["alignment"]
    typer.echo(
        f"aligned on {a['pairs_used']} pairs ({a['mode']}, {a['model']}, clock offset {a['clock_offset_s']:+.2f} s, validation RMSE {a['validation_rmse_m']:.2f} m)"
    )
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


@app.command()
def formats() -> None:
    """List the dataset formats EVP reads, in detection order."""
    from evp.io.registry import readers

    for reader in readers():
        typer.echo(f"{reader.name:14s} {reader.description}")


@app.command("eval")
def evaluate_command(
    ref: Path = typer.Argument(..., help="Reference trajectory (TUM, KITTI or EuRoC CSV)."),
    est: Path = typer.Argument(..., help="Estimated trajectory (TUM, KITTI or EuRoC CSV)."),
    align: str = typer.Option("sim3", "--align", help="none, se3 or sim3 (Umeyama)."),
    n_align: int | None = typer.Option(None, "--n-align", help="Align on the first N matched poses only."),
    max_diff: float = typer.Option(0.01, "--t-max-diff", help="Largest time difference (s) for matching poses."),
    offset: float = typer.Option(0.0, "--t-offset", help="Seconds added to the estimate's timestamps."),
    ref_times: Path | None = typer.Option(None, "--ref-times", help="times.txt for a KITTI reference."),
    est_times: Path | None = typer.Option(None, "--est-times", help="times.txt for a KITTI estimate."),
    rpe_delta: float = typer.Option(1.0, "--rpe-delta", help="RPE pair distance."),
    rpe_unit: str = typer.Option("frames", "--rpe-unit", help="frames or m."),
    z_target: float | None = typer.Option(None, "--z-target", help="Also report poses with |z_ref - Z| < --z-tol."),
    z_tol: float = typer.Option(2.0, "--z-tol", help="Tolerance (m) of the z subset."),
    json_out: Path | None = typer.Option(None, "--json", help="Write all statistics as JSON."),
    report: Path | None = typer.Option(None, "--report", help="Write plots and a Markdown summary to this folder."),
) -> None:
    """Compare an estimated trajectory with a reference: APE, RPE, XY RMSE, quartiles (evo's conventions)."""
    from evp.eval.cli_support import run_evaluation

    result = run_evaluation(ref, est, align, n_align, max_diff, offset, ref_times, est_times, rpe_delta, rpe_unit, z_target, z_tol)
    summary = result.summary()
    stats = summary["ape_translation_m"]
    typer.echo(f"matched poses {summary['matched_poses']}, alignment {align}, scale {result.alignment.scale:.6g}")
    typer.echo("APE translation (m): " + "  ".join(f"{k} {stats[k]:.6g}" for k in ("rmse", "mean", "median", "std", "min", "max", "q1", "q3", "iqr")))
    typer.echo(f"XY RMSE (m): {summary['xy_rmse']:.6g}   APE rotation RMSE (deg): {summary['ape_rotation_deg']['rmse']:.6g}")
    if "rpe" in summary:
        typer.echo(
            f"RPE ({rpe_delta:g} {rpe_unit}): translation RMSE {summary['rpe']['translation_m']['rmse']:.6g} m, rotation RMSE {summary['rpe']['rotation_deg']['rmse']:.6g} deg"
        )
    if "subset" in summary and summary["subset"]["ape_translation_m"]:
        typer.echo(f"subset {summary['subset']['rule']}: {summary['subset']['poses']} poses, RMSE {summary['subset']['ape_translation_m']['rmse']:.6g} m")
    if json_out:
        json_out.parent.mkdir(parents=True, exist_ok=True)
        json_out.write_text(json.dumps(summary, indent=2))
    if report:
        from evp.config import EvalSettings, Settings, write_settings
        from evp.eval.report import write_report

        typer.echo(f"report: {write_report(result, report, ref.name, est.name)}")
        eval_settings = EvalSettings(align=align, n_align=n_align, max_time_diff_s=max_diff, time_offset_s=offset, rpe_delta=rpe_delta, rpe_unit=rpe_unit)
        write_settings(Settings(eval=eval_settings), report)


@app.command()
def convert(
    src: Path = typer.Argument(..., help="Trajectory file (TUM, KITTI, EuRoC CSV or EVP CSV)."),
    dst: Path = typer.Argument(..., help="Output file."),
    to: str = typer.Option("tum", "--to", help="tum, kitti or csv."),
    times: Path | None = typer.Option(None, "--times", help="times.txt giving stamps to a KITTI input."),
) -> None:
    """Convert a trajectory between formats (full float precision)."""
    from evp.io.trajectory import TrajectoryFormat, read_timestamps, read_trajectory, write_trajectory

    trajectory = read_trajectory(src)
    if times is not None:
        trajectory = trajectory.with_timestamps(read_timestamps(times)[: len(trajectory)])
    try:
        fmt = TrajectoryFormat(to)
    except ValueError:
        raise EvpError(f"--to must be tum, kitti or csv, not {to!r}") from None
    if fmt is TrajectoryFormat.TUM and trajectory.timestamps is None:
        raise EvpError(f"{src} has no timestamps; give --times times.txt to write TUM")
    write_trajectory(dst, trajectory, fmt)
    typer.echo(f"wrote {len(trajectory)} poses to {dst} ({fmt.value})")


@app.command()
def calibrate(
    source: Path = typer.Argument(..., help="Folder of images or a video of the board."),
    out: Path = typer.Option(Path("camera.yaml"), "--out", help="OpenCV FileStorage YAML to write."),
    pattern: str = typer.Option("chessboard", "--pattern", help="chessboard or charuco."),
    cols: int = typer.Option(..., "--cols", help="Squares across the board."),
    rows: int = typer.Option(..., "--rows", help="Squares down the board."),
    square: float = typer.Option(..., "--square", help="Square side (m)."),
    marker: float = typer.Option(0.0, "--marker", help="ChArUco marker side (m)."),
    dictionary: str = typer.Option("DICT_4X4_50", "--dictionary", help="ArUco dictionary of a ChArUco board."),
    every: int = typer.Option(1, "--every", min=1, help="Use every N-th image or video frame."),
    k3: bool = typer.Option(False, "--k3", help="Also estimate k3 (wide lenses)."),
) -> None:
    """Calibrate a camera from chessboard or ChArUco views; bad views are rejected and reported."""
    from evp.calib.calibrate import BoardSpec, calibrate_views, images_from_path
    from evp.calib.camera_files import write_opencv_yaml

    try:
        board = BoardSpec(pattern, cols, rows, square, marker, dictionary)
    except ValueError as exc:
        raise EvpError(str(exc)) from None
    result = calibrate_views(images_from_path(source, every), board, fix_k3=not k3)
    out.parent.mkdir(parents=True, exist_ok=True)
    # the board and options used are stored beside the result, in the same file
    used = {"rms_reprojection_error_px": result.rms_px, "views_used": len(result.per_view_rms_px), "views_rejected": len(result.rejected)}
    used.update({"board_cols": cols, "board_rows": rows, "board_square_m": square, "board_marker_m": marker, "estimate_k3": int(k3), "every_nth_image": every})
    write_opencv_yaml(out, result.camera, used, {"board_pattern": pattern, "board_dictionary": dictionary})
    typer.echo(result.report())
    typer.echo(f"wrote {out}")


@app.command()
def camera(
    source: str = typer.Argument(..., help="Calibration file (OpenCV, ROS, ORB-SLAM, Kalibr, EuRoC) or profile name."),
    width: int | None = typer.Option(None, "--width", help="Rescale to this width (with --height)."),
    height: int | None = typer.Option(None, "--height", help="Rescale to this height (with --width)."),
    out: Path | None = typer.Option(None, "--out", help="Write it as OpenCV FileStorage YAML."),
) -> None:
    """Show a camera model from a file or a shipped profile (e.g. nexus5x_640x380); list profiles with 'list'."""
    from evp.calib.camera_files import write_opencv_yaml
    from evp.calib.profiles import camera_from, profile_names

    if source == "list":
        typer.echo("\n".join(profile_names()))
        return
    model = camera_from(source)
    if width and height:
        model = model.scaled(width, height)
    typer.echo(
        f"{model.name}: {model.width}x{model.height} fx {model.fx:.4f} fy {model.fy:.4f} cx {model.cx:.4f} cy {model.cy:.4f} "
        f"k1 {model.k1:g} k2 {model.k2:g} p1 {model.p1:g} p2 {model.p2:g} k3 {model.k3:g}"
    )
    if out:
        write_opencv_yaml(out, model)
        typer.echo(f"wrote {out}")


@app.command()
def serve(
    host: str = typer.Option("0.0.0.0", "--host", help="Address to listen on (0.0.0.0: every interface)."),
    port: int = typer.Option(8443, "--port", help="TCP port for the web UI, the phone page and the WebSockets."),
    data: Path = typer.Option(Path("evp-data"), "--data", help="Data folder: database, one MCAP recording per session, TLS certificate."),
    db: str | None = typer.Option(None, "--db", help="SQLAlchemy URL (default: SQLite in the data folder), e.g. postgresql://user@host/evp."),
    mavlink: str | None = typer.Option(None, "--mavlink", help="Pose to a flight controller, e.g. udpout:127.0.0.1:14540 or /dev/ttyUSB0,57600."),
    config: Path | None = typer.Option(None, "--config", help="Settings YAML (ORB, camera, SLAM, station, mavlink sections)."),
    token: str = typer.Option("", "--token", envvar="EVP_TOKEN", help="Shared secret mobile stations must send in hello (default: none)."),
    no_tls: bool = typer.Option(False, "--no-tls", help="Plain HTTP/WebSocket (behind a TLS proxy); phones then need localhost for the camera."),
) -> None:
    """Run the base station: mobile stations stream to it, operators watch it in a browser."""
    from evp.config import load_settings
    from evp.station.serve import serve as run_station

    run_station(host, port, data, load_settings(config), db, mavlink, token, not no_tls, typer.echo)


@app.command()
def stream(
    source: str = typer.Argument(..., help="Dataset/recording/video path, camera:N (local camera), or an MJPEG URL (http://phone:8080/video)."),
    url: str = typer.Option(..., "--url", help="The station, e.g. wss://192.168.1.10:8443 (ws://, http(s):// also understood)."),
    realtime: bool = typer.Option(False, "--realtime", help="Pace a recording at its own rate (else as fast as the station answers)."),
    encoding: str = typer.Option("auto", "--encoding", help="jpeg, png, raw, or auto (png for image files, jpeg otherwise)."),
    jpeg_quality: int = typer.Option(90, "--jpeg-quality", min=1, max=100),
    camera: str | None = typer.Option(None, "--camera", help="Calibration file or profile name when the source has none."),
    max_frames: int | None = typer.Option(None, "--max-frames", min=1, help="Stop after this many frames."),
    token: str = typer.Option("", "--token", envvar="EVP_TOKEN", help="The station's token, if it has one."),
    resume: str | None = typer.Option(None, "--resume", help="Continue this session (after a dropped link)."),
    cafile: str | None = typer.Option(None, "--cafile", help="The station's cert.pem, to verify it (else its fingerprint is printed)."),
    fingerprint: str | None = typer.Option(None, "--fingerprint", help="Refuse a station whose certificate has another SHA-256 fingerprint."),
    out: Path | None = typer.Option(None, "--out", help="Write the received poses here (poses.tum, summary.json)."),
    quiet: bool = typer.Option(False, "--quiet", help="Print only the summary, not each pose."),
) -> None:
    """Stream to a base station as a mobile station would; prints each pose, then a JSON summary."""
    from evp.station.cli_support import run_stream

    summary = run_stream(source, url, realtime, encoding, jpeg_quality, camera, max_frames, token, resume, cafile, fingerprint, out, quiet, typer.echo)
    typer.echo(json.dumps(summary))


@app.command()
def replay(
    session: str = typer.Argument(..., help="Session id (as listed by the station) or the path of its .mcap file."),
    data: Path = typer.Option(Path("evp-data"), "--data", help="The station's data folder."),
    db: str | None = typer.Option(None, "--db", help="SQLAlchemy URL, when the station used --db."),
    out: Path | None = typer.Option(None, "--out", help="Folder for trajectory.tum, trajectory_live.tum, comparison.json."),
    all_frames: bool = typer.Option(False, "--all-frames", help="Also estimate the frames the live station dropped as stale."),
) -> None:
    """Re-run a recorded session offline and compare with the poses sent live."""
    from evp.station.cli_support import run_replay

    typer.echo(json.dumps(run_replay(session, data, db, out, all_frames), indent=2))


@config_app.command("dump")
def config_dump(path: Path | None = typer.Argument(None, help="Settings file to load first (else the defaults).")) -> None:
    """Print the effective settings as YAML."""
    from evp.config import load_settings, settings_yaml

    typer.echo(settings_yaml(load_settings(path)), nl=False)


@vocabulary_app.command("build")
def vocabulary_build(
    sources: list[Path] = typer.Argument(
        None, metavar="[DATASET]...", help="Recordings to train on (any format evp info reads); none: EVP's rendered training scenes."
    ),
    out: Path = typer.Option(..., "--out", help="Vocabulary file to write (.npz); use it with slam.vocabulary in a settings file."),
    every: int = typer.Option(5, "--every", min=1, help="With DATASETs: every this many frames."),
    frames_per_scene: int = typer.Option(40, "--frames-per-scene", min=1, help="Without DATASETs: images rendered per training scene."),
    branching: int = typer.Option(10, "--branching", min=2, help="Children per tree node."),
    depth: int = typer.Option(4, "--depth", min=1, help="Tree levels (words: up to branching ** depth)."),
    config: Path | None = typer.Option(None, "--config", help="Settings YAML: its orb section sets the extractor (use the one tracking will use)."),
) -> None:
    """Train a vocabulary (hierarchical k-medians of ORB descriptors, DBoW2's); the one shipped
    with EVP is this command without DATASETs."""
    from rich.progress import Progress

    from evp.config import load_settings
    from evp.io.vocabulary_files import save_vocabulary
    from evp.vocabulary_training import build_vocabulary, dataset_descriptors, rendered_descriptors

    orb = load_settings(config).orb
    with Progress(transient=True) as progress:
        images = progress.add_task("extracting ORB features", total=None)
        advance = lambda: progress.advance(images)  # noqa: E731
        sets, names = dataset_descriptors(sources, every, orb, advance) if sources else rendered_descriptors(frames_per_scene, orb, advance)
        nodes = progress.add_task(f"clustering {sum(len(d) for d in sets)} descriptors", total=None)
        vocabulary = build_vocabulary(sets, names, branching, depth, orb, lambda done, total: progress.update(nodes, completed=done, total=total))
    out.parent.mkdir(parents=True, exist_ok=True)
    save_vocabulary(vocabulary, out)
    typer.echo(f"{out}: {vocabulary.n_words} words from {len(sets)} images ({vocabulary.notes['descriptors']} descriptors)")


@vocabulary_app.command("info")
def vocabulary_info(path: Path | None = typer.Argument(None, help="Vocabulary file (default: the one shipped with EVP).")) -> None:
    """What a vocabulary is: words, tree shape, what it was trained on."""
    from evp.io.vocabulary_files import default_vocabulary_path, load_vocabulary

    path = path or default_vocabulary_path()
    vocabulary = load_vocabulary(path)
    notes = vocabulary.notes
    typer.echo(f"{path}: {vocabulary.n_words} words, {vocabulary.branching} branches x {vocabulary.depth} levels")
    if notes:
        typer.echo(f"  trained on {notes.get('images', '?')} images, {notes.get('descriptors', '?')} descriptors ({notes.get('built_by', '?')})")
        for source in notes.get("trained_on", []):
            typer.echo(f"    {source}")


def main() -> None:
    """Entry point: user errors become one line on stderr (exit 2); ``--debug`` shows the traceback."""
    try:
        app()
    except EvpError as exc:
        if _state["debug"]:
            raise
        typer.echo(f"error: {exc}", err=True)
        sys.exit(2)


if __name__ == "__main__":
    main()
