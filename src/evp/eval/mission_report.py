"""What a closed-loop marker mission writes: ``mission.json`` (the figures), the trajectory, the
map, the state timeline and events, and the plots (seed 003's Figures 8 and 9, ours)."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np

from evp.eval.plots import _save  # also selects the Agg backend
from evp.sim.mission import MissionResult


def plot_flight_level(result: MissionResult, path: Path) -> Path:
    """Figure 8 as ours: the true flight level against the 200-700 mm tracking band."""
    s = result.autopilot.settings
    fig, ax = plt.subplots(figsize=(7, 3.2))
    ax.axhspan(s.band_low_m * 1000, s.band_high_m * 1000, color="tab:green", alpha=0.12, label="tracking band")
    ax.plot(result.times, result.true_positions[:, 2] * 1000, lw=1, label="flight level (true)")
    ax.plot(result.times, result.heights * 1000, ".", ms=1, color="0.4", label="sonar")
    ax.set_xlabel("time (s)")
    ax.set_ylabel("height (mm)")
    ax.legend(loc="upper right", fontsize=8)
    return _save(fig, path)


def plot_exploration(result: MissionResult, path: Path) -> Path:
    """Figure 9 as ours: markers mapped over time."""
    fig, ax = plt.subplots(figsize=(7, 3.2))
    total = len(result.marker_centres)
    ax.plot(result.times, 100.0 * result.mapped / total, lw=1.5)
    ax.axhline(95, color="tab:red", lw=0.8, ls="--", label="95 %")
    ax.set_xlabel("time (s)")
    ax.set_ylabel(f"markers mapped (% of {total})")
    ax.set_ylim(0, 102)
    ax.legend(loc="lower right", fontsize=8)
    return _save(fig, path)


def plot_top_view(result: MissionResult, path: Path) -> Path:
    """The true path, the estimated one (map frame put on the root's true place), the true marker
    centres and the mapped ones."""
    fig, ax = plt.subplots(figsize=(6, 6.6))
    truth = np.array(list(result.marker_centres.values()))
    ax.plot(truth[:, 0], truth[:, 1], "s", ms=6, mfc="none", color="0.6", label="markers")
    mapped = np.array([result.to_world(p[:2]) for p in result.autopilot.marker_map.poses.values()]).reshape(-1, 2)
    ax.plot(mapped[:, 0], mapped[:, 1], "+", color="tab:blue", label="mapped")
    ax.plot(result.true_positions[:, 0], result.true_positions[:, 1], lw=1, color="tab:orange", label="true path")
    valid = np.isfinite(result.estimated[:, 0])
    estimate = np.array([result.to_world(p[:2]) for p in result.estimated[valid]]).reshape(-1, 2)
    ax.plot(estimate[:, 0], estimate[:, 1], lw=0.6, ls="--", color="k", label="estimated path")
    if result.spec.target is not None:
        ax.plot(*result.marker_centres[result.spec.target], "*", ms=14, color="tab:red", label=f"target {result.spec.target}")
    ax.set_aspect("equal")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.legend(loc="upper right", fontsize=7)
    return _save(fig, path)


def map_record(result: MissionResult) -> dict:
    marker_map = result.autopilot.marker_map
    grid = marker_map.grid()
    return {
        "root": marker_map.root,
        "pitch_m": marker_map.pitch_m if np.isfinite(marker_map.pitch_m) else None,
        "markers": {
            str(i): {
                "pose": [float(v) for v in pose],
                "grid": list(grid[i]) if i in grid else None,
                "neighbours": {way: {"id": link.neighbour, "quality": round(link.quality, 3)} for way, link in marker_map.adjacency.get(i, {}).items()},
            }
            for i, pose in sorted(marker_map.poses.items())
        },
    }


def write_mission(result: MissionResult, directory: Path) -> dict:
    """Every output of one mission; returns the summary written to ``mission.json``."""
    directory.mkdir(parents=True, exist_ok=True)
    summary = result.summary()
    (directory / "mission.json").write_text(json.dumps(summary, indent=2) + "\n")
    with (directory / "trajectory.csv").open("w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(
            ["t_s", "x_m", "y_m", "z_m", "est_x_m", "est_y_m", "est_yaw_rad", "range_m", "state", "cmd_vx", "cmd_vy", "tilt_fwd", "tilt_left", "climb"]
        )
        for k, t in enumerate(result.times):
            c = result.commands[k]
            row = [t, *result.true_positions[k], *result.estimated[k], result.heights[k], result.states[k], *c.velocity_map, *c.tilt_body, c.climb_m_s]
            writer.writerow([f"{v:.5f}" if isinstance(v, float) else v for v in row])
    (directory / "map.json").write_text(json.dumps(map_record(result), indent=1) + "\n")
    events = sorted(result.autopilot.events + result.autopilot.marker_map.events, key=lambda e: e.time_s)
    (directory / "events.json").write_text(json.dumps([{"t_s": round(e.time_s, 3), "kind": e.kind, "detail": e.detail} for e in events], indent=1) + "\n")
    with (directory / "timeline.csv").open("w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(["t_s", "state"])
        previous = None
        for t, state in zip(result.times, result.states):
            if state != previous:
                writer.writerow([f"{t:.3f}", state])
                previous = state
    plot_flight_level(result, directory / "flight_level.png")
    plot_exploration(result, directory / "exploration.png")
    plot_top_view(result, directory / "top_view.png")
    return summary
