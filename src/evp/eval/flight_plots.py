"""Figures of an aligned flight (``evp align --out``), PNG."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.ticker import MaxNLocator  # noqa: E402

from evp.fusion.flight import NEAR_TARGET_M, FlightResult  # noqa: E402


def plot_flight_errors(result: FlightResult, out: Path) -> list[Path]:
    """Histogram and box plot of the errors against GPS (seed 002 Figs. 3, 7, 8), and the track
    over the GPS fixes with their 1-sigma circles and the alarms (Fig. 9)."""
    errors = result.errors_m
    target = result.alignment.chosen["target_altitude_m"]
    near = np.abs(result.error_heights_m - target) < NEAR_TARGET_M
    paths = []
    fig, axes = plt.subplots(1, 2, figsize=(9, 3.6), sharey=True)
    for ax, data, title in ((axes[0], errors, "whole flight"), (axes[1], errors[near], f"near target altitude (|z - {target:.0f} m| < {NEAR_TARGET_M:.0f} m)")):
        if data.size:
            ax.hist(data, bins=30, color="tab:blue", alpha=0.8)
        ax.set_title(title)
        ax.set_xlabel("horizontal error vs GPS (m)")
        ax.yaxis.set_major_locator(MaxNLocator(integer=True))  # counts of fixes: no 1.5
    axes[0].set_ylabel("fixes")
    fig.tight_layout()
    fig.savefig(out / "error_histogram.png", dpi=110)
    plt.close(fig)
    paths.append(out / "error_histogram.png")
    fig, ax = plt.subplots(figsize=(4.5, 4))
    ax.boxplot([errors, errors[near] if near.any() else [np.nan]], tick_labels=["whole flight", "near target"])
    ax.set_ylabel("horizontal error vs GPS (m)")
    fig.tight_layout()
    fig.savefig(out / "error_boxplot.png", dpi=110)
    plt.close(fig)
    paths.append(out / "error_boxplot.png")
    fig, ax = plt.subplots(figsize=(7, 6))
    gps = result.gps
    for (e, n), sigma in zip(gps.enu[:, :2], gps.horizontal_sigma_m):
        ax.add_patch(plt.Circle((e, n), sigma, color="tab:orange", alpha=0.12, lw=0))
    ax.plot(gps.enu[:, 0], gps.enu[:, 1], ".", color="tab:orange", ms=3, label="GPS (1-sigma circles)")
    aligned = result.alignment.aligned.positions
    ax.plot(aligned[:, 0], aligned[:, 1], "-", color="tab:blue", lw=1.2, label="vision aligned to GPS")
    window = (gps.times >= result.alignment.window[0]) & (gps.times <= result.alignment.window[1])
    ax.plot(gps.enu[window, 0], gps.enu[window, 1], "o", mfc="none", color="tab:green", ms=5, label="alignment pairs")
    for event in result.monitor.events:
        if event.kind == "spoofing_alarm":
            k = int(np.argmin(np.abs(gps.times - event.timestamp)))
            ax.plot(*gps.enu[k, :2], "rx", ms=12, mew=2, label="spoofing alarm")
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel("east (m)")
    ax.set_ylabel("north (m)")
    ax.legend(loc="best", fontsize=8)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(out / "trajectory_gps.png", dpi=110)
    plt.close(fig)
    paths.append(out / "trajectory_gps.png")
    return paths
