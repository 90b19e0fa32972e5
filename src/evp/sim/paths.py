"""Vehicle paths: polylines walked at set speeds, smoothed into flyable/drivable curves."""

from __future__ import annotations

import numpy as np
from scipy.ndimage import gaussian_filter1d

SAMPLE_DT = 0.05


def walk_polyline(points: np.ndarray, speeds: np.ndarray | float, dt: float = SAMPLE_DT) -> np.ndarray:
    """Positions every ``dt`` seconds along a polyline, segment i walked at ``speeds[i]`` (m/s)."""
    points = np.asarray(points, dtype=float)
    speeds = np.broadcast_to(np.asarray(speeds, dtype=float), (len(points) - 1,))
    lengths = np.linalg.norm(np.diff(points, axis=0), axis=1)
    vertex_times = np.concatenate([[0.0], np.cumsum(lengths / speeds)])
    times = np.arange(0.0, vertex_times[-1] + 1e-12, dt)
    return np.column_stack([np.interp(times, vertex_times, points[:, k]) for k in range(points.shape[1])])


def hold(position: np.ndarray, seconds: float, dt: float = SAMPLE_DT) -> np.ndarray:
    return np.tile(np.asarray(position, dtype=float), (max(1, int(round(seconds / dt))), 1))


def smooth(samples: np.ndarray, seconds: float, dt: float = SAMPLE_DT) -> np.ndarray:
    """Gaussian smoothing over ``seconds`` (rounds corners, limits acceleration and jerk)."""
    return gaussian_filter1d(samples, sigma=seconds / dt, axis=0, mode="nearest")


def fit_duration(samples: np.ndarray, duration_s: float | None, dt: float = SAMPLE_DT) -> np.ndarray:
    """Cut the path, or extend it by hovering at its end, to last ``duration_s`` seconds."""
    if duration_s is None:
        return samples
    wanted = int(round(duration_s / dt)) + 1
    if len(samples) >= wanted:
        return samples[:wanted]
    return np.vstack([samples, np.tile(samples[-1], (wanted - len(samples), 1))])


def lawnmower(width: float, height: float, spacing: float) -> np.ndarray:
    """Back-and-forth lines along x covering a width x height area centred on the origin."""
    count = max(2, int(np.ceil(height / spacing)) + 1)
    ys = np.linspace(-height / 2, height / 2, count)
    points = []
    for i, y in enumerate(ys):
        xs = (-width / 2, width / 2) if i % 2 == 0 else (width / 2, -width / 2)
        points += [(xs[0], y), (xs[1], y)]
    return np.array(points)


def loops(width: float, height: float, turns: int = 3, samples: int = 400) -> np.ndarray:
    """Manual-like loops: a figure of eight overlaid on an ellipse, filling width x height."""
    s = np.linspace(0, 2 * np.pi * turns, samples)
    return np.column_stack([width / 2 * np.sin(s), height / 2 * np.sin(2 * s) * 0.5 + height / 4 * np.cos(s / turns)])


def random_waypoints(rng: np.random.Generator, width: float, height: float, count: int) -> np.ndarray:
    return np.column_stack([rng.uniform(-width / 2, width / 2, count), rng.uniform(-height / 2, height / 2, count)])
