"""Evaluation report: figures, metrics.json and a Markdown summary in one folder."""

from __future__ import annotations

import json
from pathlib import Path

from evp.eval.evaluate import EvaluationResult
from evp.eval.plots import write_plots

ROWS = ("rmse", "mean", "median", "std", "min", "max", "q1", "q3", "iqr")


def markdown_summary(result: EvaluationResult, ref_name: str, est_name: str) -> str:
    summary = result.summary()
    lines = [
        f"# Trajectory evaluation: `{est_name}` vs `{ref_name}`",
        "",
        f"- matched poses: {summary['matched_poses']} "
        + (
            "by frame number (the KITTI files came without times)"
            if result.frame_indexed
            else f"(max time difference {result.options.max_time_diff_s:.4g} s, offset {result.options.time_offset_s:g} s)"
        ),
        f"- alignment: {result.options.align}"
        + (f" on the first {result.options.n_align} poses" if result.options.n_align else "")
        + f", scale {result.alignment.scale:.6g}",
        *(
            ["- alignment is degenerate (collinear positions): the rotation about that line is not observable, so no APE rotation"]
            if result.alignment.degenerate
            else []
        ),
        f"- reference path length: {summary['reference_path_length_m']:.3f} m",
        f"- XY RMSE: {summary['xy_rmse']:.6g} m",
        *([f"- in-plane RMSE ({summary['plane']}, the plane the reference moves in): {summary['plane_rmse']:.6g} m"] if summary["plane"] != "xy" else []),
        *([] if summary["reference_orientation"] else ["- the reference measures positions only: no rotation error or RPE"]),
        "",
        "| statistic | APE translation (m) | APE XY (m) |" + (" APE rotation (deg) |" if "ape_rotation_deg" in summary else ""),
        "|---|---|---|" + ("---|" if "ape_rotation_deg" in summary else ""),
    ]
    for row in ROWS:
        rotation = f" {summary['ape_rotation_deg'][row]:.6g} |" if "ape_rotation_deg" in summary else ""
        lines.append(f"| {row} | {summary['ape_translation_m'][row]:.6g} | {summary['ape_translation_xy_m'][row]:.6g} |{rotation}")
    if "rpe" in summary:
        rpe = summary["rpe"]
        lines += [
            "",
            f"RPE over {rpe['pairs']} pairs {rpe['delta']:g} {rpe['unit']} apart: translation RMSE {rpe['translation_m']['rmse']:.6g} m, rotation RMSE {rpe['rotation_deg']['rmse']:.6g} deg",
        ]
    if "subset" in summary and summary["subset"]["ape_translation_m"]:
        sub = summary["subset"]
        lines += [
            "",
            f"Subset {sub['rule']}: {sub['poses']} poses, APE RMSE {sub['ape_translation_m']['rmse']:.6g} m, mean {sub['ape_translation_m']['mean']:.6g} m, max {sub['ape_translation_m']['max']:.6g} m",
        ]
    lines += ["", "![top view](top_view.png)", "![APE over time](ape_over_time.png)", "![histogram](ape_histogram.png)", "![box plot](ape_boxplot.png)", ""]
    return "\n".join(lines)


def write_report(result: EvaluationResult, directory: Path, ref_name: str, est_name: str) -> Path:
    """Figures, ``metrics.json`` and ``report.md`` into ``directory``; returns the Markdown path."""
    directory.mkdir(parents=True, exist_ok=True)
    write_plots(result, directory)
    (directory / "metrics.json").write_text(json.dumps(result.summary(), indent=2))
    report = directory / "report.md"
    report.write_text(markdown_summary(result, ref_name, est_name))
    return report
