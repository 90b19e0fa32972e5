"""``evp calibrate`` and ``evp camera``: a camera model from board views, from a file or from a profile."""

from __future__ import annotations

from pathlib import Path

import typer

from evp.errors import UsageError
from evp.io.output_paths import writable_file

app = typer.Typer()


@app.command()
def calibrate(
    source: Path = typer.Argument(..., help="Folder of images or a video of the board."),
    out: Path = typer.Option(Path("camera.yaml"), "--out", help="OpenCV FileStorage YAML to write."),
    pattern: str = typer.Option("chessboard", "--pattern", help="chessboard or charuco."),
    cols: int = typer.Option(..., "--cols", help="Squares across the board (inner corners + 1)."),
    rows: int = typer.Option(..., "--rows", help="Squares down the board (inner corners + 1)."),
    square: float = typer.Option(..., "--square", help="Square side (m)."),
    marker: float = typer.Option(0.0, "--marker", help="ChArUco marker side (m)."),
    dictionary: str = typer.Option("DICT_4X4_50", "--dictionary", help="ArUco dictionary of a ChArUco board."),
    every: int = typer.Option(1, "--every", min=1, help="Use every N-th image or video frame."),
    k3: bool = typer.Option(False, "--k3", help="Also estimate k3 (wide lenses)."),
) -> None:
    """Calibrate a camera from chessboard or ChArUco views; bad views are rejected and reported."""
    from evp.calib.calibrate import BoardSpec, calibrate_views, images_from_path
    from evp.calib.camera_files import write_opencv_yaml

    writable_file(out, example="camera.yaml")
    board = BoardSpec(pattern, cols, rows, square, marker, dictionary)
    result = calibrate_views(images_from_path(source, every), board, fix_k3=not k3, source=str(source))
    out.parent.mkdir(parents=True, exist_ok=True)
    # the board and options used are stored beside the result, in the same file
    used = {"rms_reprojection_error_px": result.rms_px, "views_used": len(result.per_view_rms_px), "views_rejected": len(result.rejected)}
    used.update({"board_cols": cols, "board_rows": rows, "board_square_m": square, "board_marker_m": marker, "estimate_k3": int(k3), "every_nth_image": every})
    write_opencv_yaml(out, result.camera, used, {"board_pattern": pattern, "board_dictionary": dictionary})
    typer.echo(result.report())
    typer.echo(f"wrote {out}")


@app.command()
def camera(
    source: str = typer.Argument(..., help="Calibration file (OpenCV, ROS, ORB-SLAM, Kalibr, EuRoC, calib.txt) or profile name; 'list' lists the profiles."),
    width: int | None = typer.Option(None, "--width", min=1, help="Image width: rescale to it (with --height), or the size a calib.txt lacks."),
    height: int | None = typer.Option(None, "--height", min=1, help="Image height (with --width)."),
    to: str | None = typer.Option(None, "--to", help="Convert: yaml (OpenCV FileStorage), ros (camera_info) or txt (calib.txt numbers); printed unless --out."),
    out: Path | None = typer.Option(None, "--out", help="Write the converted file here (format from --to, else yaml; .txt: txt)."),
) -> None:
    """Show a camera model from a file or a shipped profile (e.g. nexus5x_640x380), or convert it
    between the calibration formats every command reads (--to)."""
    from evp.calib.camera_files import CAMERA_FILE_WRITERS
    from evp.calib.profiles import camera_from, profile_names
    from evp.types import LensModel

    if source == "list":
        typer.echo("\n".join(profile_names()))
        return
    if (width is None) != (height is None):
        raise UsageError("give both --width and --height, or neither")
    fmt = to or ("txt" if out is not None and out.suffix.lower() == ".txt" else "yaml")
    if fmt not in CAMERA_FILE_WRITERS:
        raise UsageError(f"--to {to!r}: choose one of {', '.join(CAMERA_FILE_WRITERS)}")
    writable_file(out, example="camera.yaml")
    model = camera_from(source, (width, height) if width and height else None)
    summary = (
        f"{model.name}: {model.width}x{model.height} fx {model.fx:.4f} fy {model.fy:.4f} cx {model.cx:.4f} cy {model.cy:.4f} "
        + " ".join(f"{name} {value:g}" for name, value in model.coefficients.items())
        + ("" if model.lens is LensModel.RADTAN else f" ({model.lens.value})")
    )
    if to is not None and out is None:
        typer.echo(CAMERA_FILE_WRITERS[fmt](model), nl=False)
        return
    typer.echo(summary)
    if out:
        out.write_text(CAMERA_FILE_WRITERS[fmt](model))
        typer.echo(f"wrote {out} ({fmt})")
