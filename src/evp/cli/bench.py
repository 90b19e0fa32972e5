"""``evp bench``: the measurements of the papers' speed studies that need no harness of their own."""

from __future__ import annotations

import json
from pathlib import Path

import typer

from evp.io.output_paths import writable_file

app = typer.Typer(help="Speed studies of the papers (the full benchmark suite is bench/, see bench/README.md).", no_args_is_help=True)


@app.command("features")
def bench_features(
    shared: Path | None = typer.Option(
        None, "--data", help="The shared data folder holding EuRoC MH01 and KITTI 06 (default: $EVP_SHARED_DATA, else ../shared/data)."
    ),
    pairs: int = typer.Option(20, "--pairs", min=2, help="Consecutive frame pairs, half from each recording."),
    json_out: Path | None = typer.Option(None, "--json", help="Also write the records as JSON."),
) -> None:
    """Seed 001's Figure 4 today: detection + description and matching time, and match quality, of
    OpenCV's ORB, SIFT, AKAZE, BRISK and SURF (those installed) at QVGA, 640x380 and VGA, one thread."""
    import cv2

    from evp.errors import DataError
    from evp.eval.feature_timing import absent_note, frame_pairs, measure_all
    from evp.experiments.shared_data import shared_data_folder

    writable_file(json_out, "--json", "features.json")
    folder = shared if shared is not None else shared_data_folder("")
    cv2.setNumThreads(1)
    images = frame_pairs(folder, pairs)
    if not images:
        raise DataError(f"{folder}: no frames of euroc_mh_01_easy_moving_360 or kitti_odom_06_f000-050 there (give --data)")
    typer.echo(f"{len(images)} frame pairs from {folder}, OpenCV {cv2.__version__}, one thread")
    typer.echo("detector  size           keypoints  detect+describe ms  match ms  matches  RANSAC inliers")
    records = []
    for record in measure_all(images):
        records.append(record)
        typer.echo(
            f"{record['detector']:9s} {record['size']:14s} {record['keypoints']:9.0f}  {record['detect_ms']:18.1f}  {_number(record['match_ms'], 8, 1)}"
            f"  {_number(record['matches'], 7, 0)}  {_number(record['inlier_percent'], 13, 0)} %"
        )
    note = absent_note()
    if note:
        typer.echo(note)
    if json_out is not None:
        json_out.write_text(json.dumps({"pairs": len(images), "opencv": cv2.__version__, "records": records, "note": note}, indent=1))


def _number(value: float | None, width: int, decimals: int) -> str:
    return f"{'n/a':>{width}s}" if value is None else f"{value:{width}.{decimals}f}"
