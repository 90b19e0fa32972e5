"""Seed 002's figures from the flights' records (``seed002_flights.fly``): the altitude in 2D+baro
and 3D+baro modes (Figs 1-2), error histograms for the whole flight and near the target altitude
(Figs 3-4), the aligned track over GPS with its uncertainty circles (Figs 5-6), and box plots of
each flight's errors with the errors scattered over them (Figs 7-8)."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.patches import Circle  # noqa: E402

from evp.experiments.seed002_flights import MODES, SCORED_ABOVE_M  # noqa: E402
from evp.fusion.flight import NEAR_TARGET_M  # noqa: E402


def _first(records: dict, preferred: list[str]) -> str | None:
    return next((f for f in preferred if f in records), next(iter(records), None))


def _save(fig, out: Path, name: str) -> str:
    fig.tight_layout()
    fig.savefig(out / name, dpi=110)
    plt.close(fig)
    return name


def altitude_figure(flight: str, record: dict, out: Path) -> str:
    fig, ax = plt.subplots(figsize=(9, 4))
    times, _, _, z = record["truth_series"]
    ax.plot(times, z, "k--", lw=1, label="truth")
    for mode in MODES:
        t, _, _, up = record[mode]["track"]
        ax.plot(t, up, lw=0.9, label=mode)
    ax.set(xlabel="time (s)", ylabel="altitude (m)", title=f"Flight {flight}: 2D vs 3D (Figs 1-2)")
    ax.grid(alpha=0.3)
    ax.legend()
    return _save(fig, out, f"altitude_{flight}.png")


def histogram_figure(flight: str, record: dict, out: Path) -> str:
    fig, axes = plt.subplots(1, 2, figsize=(11, 4), sharey=False)
    target = record["target_altitude_m"] + 0.3
    whole = f"whole flight (above {SCORED_ABOVE_M:g} m)"
    for ax, part in zip(axes, (whole, f"|z - target| < {NEAR_TARGET_M:g} m")):
        for mode in MODES:
            errors, heights = (np.asarray(v) for v in record[mode]["errors"])
            chosen = errors[heights > SCORED_ABOVE_M] if part == whole else errors[np.abs(heights - target) < NEAR_TARGET_M]
            ax.hist(chosen, bins=30, alpha=0.55, label=mode)
        ax.set(xlabel="horizontal error against GPS (m)", ylabel="fixes", title=f"Flight {flight}, {part}")
        ax.grid(alpha=0.3)
        ax.legend()
    return _save(fig, out, f"histogram_{flight}.png")


def track_figure(flight: str, record: dict, out: Path) -> str:
    fig, ax = plt.subplots(figsize=(7, 7))
    _, east, north, _, sigma = record["gps"]
    for e, n, s in list(zip(east, north, sigma))[::5]:
        ax.add_patch(Circle((e, n), 2 * s, fill=False, color="tab:orange", alpha=0.3, lw=0.6))
    ax.plot(east, north, ".", ms=2, color="tab:orange", label="GPS (circles: 2 sigma)")
    _, x, y, _ = record["3d+baro"]["track"]
    ax.plot(x, y, lw=1, color="tab:blue", label="visual, aligned (3D+baro)")
    ax.set_aspect("equal", adjustable="datalim")
    ax.set(xlabel="east (m)", ylabel="north (m)", title=f"Flight {flight}: track and GPS (Figs 5-6)")
    ax.grid(alpha=0.3)
    ax.legend()
    return _save(fig, out, f"track_{flight}.png")


def boxplot_figure(records: dict, out: Path) -> str:
    fig, ax = plt.subplots(figsize=(max(6, 1.2 * len(records)), 4.5))
    flights = list(records)
    errors = [np.asarray(records[f]["3d+baro"]["errors"][0]) for f in flights]
    ax.boxplot(errors, showfliers=True)
    rng = np.random.default_rng(0)
    for i, e in enumerate(errors, start=1):
        shown = e[::5]  # the paper's one-fifth subsample
        ax.plot(i + rng.uniform(-0.15, 0.15, len(shown)), shown, ".", ms=2, alpha=0.4, color="tab:gray")
    ax.set_xticks(range(1, len(flights) + 1), flights)
    ax.set(xlabel="flight", ylabel="horizontal error against GPS (m)", title="3D+baro errors per flight (Figs 7-8)")
    ax.grid(alpha=0.3, axis="y")
    return _save(fig, out, "boxplots.png")


def plot_all(records: dict[str, dict], out: Path) -> list[str]:
    if not records:
        return []
    names = [altitude_figure(f, records[f], out) for f in [_first(records, ["G"])]]
    names += [histogram_figure(f, records[f], out) for f in [f for f in ("A", "C") if f in records] or [_first(records, [])]]
    names += [track_figure(f, records[f], out) for f in [_first(records, ["I", "J", "L", "O"])]]
    names.append(boxplot_figure(records, out))
    return names
