"""``evp eval`` and ``evp convert``: trajectory files compared with a reference, and converted."""

from __future__ import annotations

import json
from pathlib import Path

import typer

from evp.errors import DataError, EvaluationError, UsageError
from evp.io.output_paths import writable_file, writable_folder

app = typer.Typer()


def _stamped(trajectory, times: Path | None, other, label: str):
    """KITTI poses get their ``times.txt`` stamps, or, facing another KITTI file, their frame index."""
    import numpy as np

    from evp.io.trajectory import read_timestamps

    if trajectory.timestamps is not None:
        return trajectory
    if times is not None:
        stamps = read_timestamps(times)
        if len(stamps) < len(trajectory):
            raise EvaluationError(f"{times} has {len(stamps)} times for {len(trajectory)} {label} poses")
        return trajectory.with_timestamps(stamps[: len(trajectory)])
    if other.timestamps is None or bool(np.all(np.mod(other.timestamps, 1.0) == 0)):
        return trajectory.with_timestamps(np.arange(len(trajectory), dtype=float))
    raise EvaluationError(f"the {label} is a KITTI file without times and the other trajectory has timestamps: give --{label[:3]}-times times.txt")


def evaluate_files(ref_path: Path, est_path: Path, settings, ref_times: Path | None = None, est_times: Path | None = None):
    """Read both trajectory files (KITTI ones stamped) and evaluate them with ``settings`` (EvalSettings)."""
    from dataclasses import replace

    from evp.eval.evaluate import evaluate
    from evp.io.trajectory import read_trajectory

    ref = read_trajectory(ref_path)
    est = read_trajectory(est_path)
    ref_stamped = _stamped(ref, ref_times, est, "reference")
    est_stamped = _stamped(est, est_times, ref_stamped, "estimate")
    frame_indexed = (ref.timestamps is None and ref_times is None) or (est.timestamps is None and est_times is None)
    return replace(evaluate(ref_stamped, est_stamped, settings), frame_indexed=frame_indexed)


def says_position_only(path: Path) -> bool:
    """Whether a trajectory file's leading comment says its orientation is a placeholder ('position
    only', as the shared datasets' GPS references state)."""
    try:
        with path.open() as handle:
            head = [line for _, line in zip(range(5), handle) if line.startswith("#")]
    except (OSError, UnicodeDecodeError):
        return False
    return any("position only" in line.lower().replace("-", " ").replace("_", " ") for line in head)


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
    position_only: bool | None = typer.Option(
        None,
        "--position-only/--with-orientation",
        help="The reference measures positions only (GPS): no rotation error or RPE (default: a reference whose header says 'position only').",
    ),
    plane: str = typer.Option("auto", "--plane", help="Plane of the top view and the in-plane error: auto (the one the reference moves in), xy, xz or yz."),
) -> None:
    """Compare an estimated trajectory with a reference: APE, RPE, XY RMSE, quartiles (evo's conventions)."""
    from pydantic import ValidationError

    from evp.config import EvalSettings, validation_message

    writable_file(json_out, "--json", "metrics.json")
    writable_folder(report, "--report")
    try:
        settings = EvalSettings(
            align=align,
            n_align=n_align,
            max_time_diff_s=max_diff,
            time_offset_s=offset,
            rpe_delta=rpe_delta,
            rpe_unit=rpe_unit,
            z_target_m=z_target,
            z_tolerance_m=z_tol,
            rotation=not (says_position_only(ref) if position_only is None else position_only),
            plane=plane,
        )
    except ValidationError as exc:
        raise UsageError(f"bad option: {validation_message(exc)} (align: none/se3/sim3, rpe unit: frames/m, plane: auto/xy/xz/yz)") from None
    result = evaluate_files(ref, est, settings, ref_times, est_times)
    summary = result.summary()
    stats = summary["ape_translation_m"]
    typer.echo(
        f"matched poses {summary['matched_poses']}"
        + (" by frame number (no times: --ref-times/--est-times give them)" if result.frame_indexed else "")
        + f", alignment {align}, scale {result.alignment.scale:.6g}"
    )
    typer.echo("APE translation (m): " + "  ".join(f"{k} {stats[k]:.6g}" for k in ("rmse", "mean", "median", "std", "min", "max", "q1", "q3", "iqr")))
    line = f"XY RMSE (m): {summary['xy_rmse']:.6g}"
    if summary["plane"] != "xy":
        line += f"   in-plane ({summary['plane']}) RMSE (m): {summary['plane_rmse']:.6g}"
    if "ape_rotation_deg" in summary:
        line += f"   APE rotation RMSE (deg): {summary['ape_rotation_deg']['rmse']:.6g}"
    elif not summary["reference_orientation"]:
        line += "   (position-only reference: no rotation error or RPE)"
    else:
        line += "   (collinear path: the rotation about it is not observable, no APE rotation)"
    typer.echo(line)
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
        from evp.config import Settings, write_settings
        from evp.eval.report import write_report

        typer.echo(f"report: {write_report(result, report, ref.name, est.name)}")
        write_settings(Settings(eval=settings), report)


@app.command()
def convert(
    src: Path = typer.Argument(..., help="Trajectory file (TUM, KITTI, EuRoC CSV or EVP CSV)."),
    dst: Path = typer.Argument(..., help="Output file."),
    to: str = typer.Option("tum", "--to", help="tum, kitti or csv."),
    times: Path | None = typer.Option(None, "--times", help="times.txt giving stamps to a KITTI input."),
) -> None:
    """Convert a trajectory between formats (full float precision)."""
    from evp.io.trajectory import TrajectoryFormat, read_timestamps, read_trajectory, write_trajectory

    writable_file(dst, "DST", "poses.tum")
    trajectory = read_trajectory(src)
    if times is not None:
        stamps = read_timestamps(times)
        if len(stamps) < len(trajectory):
            raise DataError(f"{times} has {len(stamps)} times for the {len(trajectory)} poses of {src}")
        trajectory = trajectory.with_timestamps(stamps[: len(trajectory)])
    try:
        fmt = TrajectoryFormat(to)
    except ValueError:
        raise UsageError(f"--to must be tum, kitti or csv, not {to!r}") from None
    if fmt is TrajectoryFormat.TUM and trajectory.timestamps is None:
        raise UsageError(f"{src} has no timestamps; give --times times.txt to write TUM")
    write_trajectory(dst, trajectory, fmt)
    typer.echo(f"wrote {len(trajectory)} poses to {dst} ({fmt.value})")
