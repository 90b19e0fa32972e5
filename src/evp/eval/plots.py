"""evo-style evaluation figures (PNG): top view (in the plane the path lies in), error over time,
histogram, box plot; metres on every axis, ticks at round numbers without offsets. A run without
ground truth gets its trajectory drawn alone."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.ticker import MaxNLocator, ScalarFormatter  # noqa: E402

from evp.eval.evaluate import EvaluationResult  # noqa: E402
from evp.eval.plane import motion_plane  # noqa: E402
from evp.types import Trajectory  # noqa: E402


def _save(fig, path: Path) -> Path:
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


# coordinates beyond this (UTM eastings, ECEF) are drawn relative to the first reference pose, so
# the ticks read as metres travelled instead of a shared offset printed beside the axis
LARGE_COORDINATE_M = 1e4


def readable_axes(ax, max_ticks: int = 7) -> None:
    """Ticks at round numbers, no scientific offset (matplotlib's default for big or tiny ranges,
    which a reader has to add back in their head)."""
    for axis in (ax.xaxis, ax.yaxis):
        axis.set_major_locator(MaxNLocator(max_ticks, steps=[1, 2, 2.5, 5, 10]))
        axis.set_major_formatter(ScalarFormatter(useOffset=False))


def plot_top_view(result: EvaluationResult, path: Path) -> Path:
    """Reference dashed grey, estimate coloured by its APE translation error, in the plane the
    reference moves in (evp.eval.plane), in metres on equal axes."""
    plane = result.plane
    ref = plane.project(result.ref.positions)
    est = plane.project(result.est.positions)
    labels = plane.labels
    if np.abs(ref).max(initial=0.0) > LARGE_COORDINATE_M:
        origin = ref[0].copy()
        ref, est = ref - origin, est - origin
        labels = tuple(label.replace(" (m)", " from the first pose (m)") for label in labels)
    fig, ax = plt.subplots(figsize=(6.4, 5.6))
    ax.plot(ref[:, 0], ref[:, 1], "--", color="0.45", label="reference")
    points = ax.scatter(est[:, 0], est[:, 1], c=result.ape_translation, s=6, cmap="viridis", label="estimate")
    ax.plot(est[:, 0], est[:, 1], "-", color="0.2", lw=0.5, alpha=0.5)
    fig.colorbar(points, ax=ax, label="APE translation (m)")
    ax.set_xlabel(labels[0])
    ax.set_ylabel(labels[1])
    ax.set_aspect("equal", adjustable="datalim")
    view = {"xy": "Top view (x-y)", "principal": "Plane of the motion"}.get(plane.name, f"{plane.name[0]}-{plane.name[1]} plane")
    ax.set_title(f"{view}, {result.options.align} alignment")
    ax.legend(loc="best")
    ax.grid(alpha=0.3)
    readable_axes(ax)
    return _save(fig, path)


def plot_trajectory(trajectory: Trajectory, path: Path, metric: bool, plane_choice: str = "auto") -> Path:
    """A run without ground truth: its trajectory alone, in the plane it moves in, from its start
    to its end; metres when the run is metric (IMU fused), else the map's own units (monocular)."""
    plane = motion_plane(trajectory.positions, plane_choice)
    xy = plane.project(trajectory.positions)
    labels = plane.labels if metric else tuple(label.replace("(m)", "(map units)") for label in plane.labels)
    fig, ax = plt.subplots(figsize=(6.4, 5.6))
    ax.plot(xy[:, 0], xy[:, 1], "-", color="tab:blue", lw=1.2, label="estimate")
    ax.plot(*xy[0], "o", color="tab:green", label="start")
    ax.plot(*xy[-1], "s", color="tab:red", label="end")
    ax.set_xlabel(labels[0])
    ax.set_ylabel(labels[1])
    ax.set_aspect("equal", adjustable="datalim")
    view = {"xy": "top view (x-y)", "principal": "plane of the motion"}.get(plane.name, f"{plane.name[0]}-{plane.name[1]} plane")
    ax.set_title(f"Estimated trajectory, {view}" + ("" if metric else "\nscale unknown (monocular, no IMU fused)"))
    ax.legend(loc="best")
    ax.grid(alpha=0.3)
    readable_axes(ax)
    return _save(fig, path)


def plot_error_over_time(result: EvaluationResult, path: Path) -> Path:
    errors = result.ape_translation
    t = result.ref.timestamps - result.ref.timestamps[0]
    fig, ax = plt.subplots(figsize=(8.2, 3.6))
    ax.plot(t, errors, color="tab:blue", lw=1.0, label="APE")
    for name, style in (("rmse", "-"), ("mean", "--"), ("median", ":")):
        value = float(np.sqrt(np.mean(errors**2))) if name == "rmse" else float(getattr(np, name)(errors))
        ax.axhline(value, ls=style, color="tab:red" if name == "rmse" else "0.3", lw=1.0, label=f"{name} {value:.4g} m")
    ax.fill_between(t, np.mean(errors) - np.std(errors), np.mean(errors) + np.std(errors), color="0.8", alpha=0.5, label="std")
    ax.set_xlabel("frame (no times given)" if result.frame_indexed else "time (s)")
    ax.set_ylabel("APE translation (m)")
    ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=8)  # beside the curve, never over it
    ax.grid(alpha=0.3)
    readable_axes(ax)
    return _save(fig, path)


def plot_histogram(result: EvaluationResult, path: Path) -> Path:
    fig, ax = plt.subplots(figsize=(5.2, 3.6))
    ax.hist(result.ape_translation, bins=min(50, max(5, len(result.ape_translation) // 10)), color="tab:blue", alpha=0.8)
    ax.set_xlabel("APE translation (m)")
    ax.set_ylabel("poses")
    ax.grid(alpha=0.3)
    readable_axes(ax)
    ax.yaxis.set_major_locator(MaxNLocator(7, integer=True))  # counts of poses: no 2.5
    return _save(fig, path)


def plot_boxplot(result: EvaluationResult, path: Path) -> Path:
    data = [result.ape_translation, result.ape_translation_plane]
    labels = ["3-D", result.plane.name.upper() if result.plane.name != "principal" else "in plane"]
    if result.subset_mask is not None and result.subset_mask.any():
        data.append(result.ape_translation[result.subset_mask])
        labels.append(f"|z-{result.options.z_target_m:g}|<{result.options.z_tolerance_m:g}")
    fig, ax = plt.subplots(figsize=(4.8, 3.8))
    ax.boxplot(data, tick_labels=labels)
    ax.set_ylabel("APE translation (m)")
    ax.grid(alpha=0.3)
    return _save(fig, path)


def write_plots(result: EvaluationResult, directory: Path) -> list[Path]:
    """All four figures into ``directory``; returns their paths."""
    directory.mkdir(parents=True, exist_ok=True)
    return [
        plot_top_view(result, directory / "top_view.png"),
        plot_error_over_time(result, directory / "ape_over_time.png"),
        plot_histogram(result, directory / "ape_histogram.png"),
        plot_boxplot(result, directory / "ape_boxplot.png"),
    ]
