"""The visual map's similarity to the world, fitted on the GPS fixes of the trusted phase: what the
navigation stage holds while GPS is lost or spoofed (seed 002's alignment of the visual track to
GPS, kept after the alignment phase).

While GPS is trusted each fix is paired with the camera's position in the visual map at the fix's
time (interpolated between the tracked poses around it). When trust is lost, the similarity
``world = scale * R @ map + t`` is fitted to every pair since the map last jumped (Umeyama,
pairs further than the chi-square bound from the fit dropped and the fit repeated: a spoofer's
pull-off before the alarm, a bad fix). Its covariance is the linear least-squares one, the
residuals' variance over the pairs counted as independent only once per GPS error correlation
time (a receiver's error is shared by a minute of fixes). The filter's own scale and map attitude
come from the IMU against SLAM's local geometry, which SLAM bends by a degree or so from place to
place; the fit over the whole phase sees the map's geometry at large (docs/decisions.md).
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

import numpy as np
from scipy.stats import chi2

from evp.geometry.alignment import umeyama
from evp.geometry.transforms import skew

OUTLIER_PROBABILITY = 0.999  # a pair whose residual is beyond this chi-square quantile (3 dof) is dropped
TRIM_ROUNDS = 3  # fits, each without the pairs the last one dropped and with the lever at its scale
MIN_PAIRS = 10
# The newest pairs kept: ten GPS error correlation times (a minute each) average the receiver's
# error down by a factor of three, more add SLAM's drift over the span (0.5-0.8 % of scale over
# 300 s, docs/decisions.md) and memory over a long session (36 000 pairs an hour at 10 Hz).
MAX_SPAN_S = 600.0
MEDIAN_CHI2_3 = float(chi2.ppf(0.5, 3))  # median of a squared 3-D Gaussian residual, in variances
RESIDUAL_FLOOR_M = 0.01  # no fix is better than an RTK receiver's centimetre: closer pairs are never dropped


@dataclass(frozen=True)
class MapFit:
    """``world = scale * R_world_map @ map + t_world_map``, fitted on ``pairs`` fixes spanning
    ``span_s`` (RMS residual ``residual_m``); ``covariance`` (7 x 7) of the log scale, the map's
    attitude (a world-frame rotation error) and the translation."""

    scale: float
    R_world_map: np.ndarray
    t_world_map: np.ndarray
    covariance: np.ndarray
    pairs: int
    dropped: int
    residual_m: float
    span_s: float


class GpsMapPairs:
    """Trusted fixes paired with the vehicle's visual-map position at their time. A fix is the
    body's position (the IMU's; the antenna is taken to be there); the map has the camera's, so each
    pair keeps the camera's position and the camera-to-body lever turned into the map (metres),
    which the fit divides by the scale it finds."""

    def __init__(self, T_body_cam: np.ndarray, max_pose_gap_s: float = 0.25, max_span_s: float = MAX_SPAN_S):
        T_body_cam = np.asarray(T_body_cam, float)
        self.R_cam_body = T_body_cam[:3, :3].T
        self.t_cam_body = -self.R_cam_body @ T_body_cam[:3, 3]  # the body's origin in the camera frame, metres
        self.max_pose_gap_s = max_pose_gap_s  # fixes between poses further apart are not paired (tracking paused)
        self.max_span_s = max_span_s
        self.clear()

    def __len__(self) -> int:
        return len(self.times)

    def clear(self) -> None:
        """No pairs (the visual map jumped, or the world changed: the pairs so far belong to another)."""
        self._fixes: list[tuple[float, np.ndarray]] = []  # not yet paired: after the newest pose
        self._last_pose: tuple[float, np.ndarray, np.ndarray] | None = None
        self.times: deque[float] = deque()
        self.camera_positions: deque[np.ndarray] = deque()  # map units
        self.levers: deque[np.ndarray] = deque()  # camera to body, map axes, metres
        self.world_positions: deque[np.ndarray] = deque()

    def add_fix(self, timestamp: float, world: np.ndarray) -> None:
        self._fixes.append((timestamp, np.asarray(world, float)))

    def add_pose(self, timestamp: float, T_map_cam: np.ndarray) -> None:
        """A tracked pose: the fixes since the last one are paired by interpolation."""
        position, lever = T_map_cam[:3, 3].copy(), T_map_cam[:3, :3] @ self.t_cam_body
        last, self._last_pose = self._last_pose, (timestamp, position, lever)
        waiting, self._fixes = self._fixes, [f for f in self._fixes if f[0] > timestamp]
        if last is None or not 0 < timestamp - last[0] <= self.max_pose_gap_s:
            return
        for t, world in waiting:
            if last[0] <= t <= timestamp:
                w = (t - last[0]) / (timestamp - last[0])
                self.times.append(t)
                self.camera_positions.append((1 - w) * last[1] + w * position)
                self.levers.append((1 - w) * last[2] + w * lever)
                self.world_positions.append(world)
        while self.times and self.times[0] < timestamp - self.max_span_s:
            for pairs in (self.times, self.camera_positions, self.levers, self.world_positions):
                pairs.popleft()

    def fit(self, before: float, min_spread_m: float, correlation_time_s: float) -> MapFit | str:
        """The fit on the pairs up to ``before``, or why there is none."""
        keep = np.asarray(self.times) <= before
        if keep.sum() < MIN_PAIRS:
            return f"{int(keep.sum())} GPS fixes paired with the visual map since it last jumped (at least {MIN_PAIRS} needed)"
        times = np.asarray(self.times)[keep]
        cameras, levers = np.asarray(self.camera_positions)[keep], np.asarray(self.levers)[keep]
        target = np.asarray(self.world_positions)[keep]
        spread = float(np.sqrt(np.mean(np.sum((target - target.mean(axis=0)) ** 2, axis=1))))  # a climb's height counts
        if spread < min_spread_m:
            return f"the paired fixes spread {spread:.1f} m, short of {min_spread_m:.0f} m"
        inliers = np.ones(len(target), bool)
        bound = chi2.ppf(OUTLIER_PROBABILITY, 3)
        scale = umeyama(cameras, target, with_scale=True).scale  # for the lever, which is small against the spread
        for _ in range(TRIM_ROUNDS):
            source = cameras + levers / scale
            similarity = umeyama(source[inliers], target[inliers], with_scale=True)
            if similarity.degenerate:
                return "the paired fixes lie on a line: the rotation about it is unknown"
            scale = similarity.scale
            residuals = np.sum((similarity.apply(source) - target) ** 2, axis=1)
            variance = float(np.mean(residuals[inliers])) / 3.0
            robust_variance = max(float(np.median(residuals[inliers])) / MEDIAN_CHI2_3, RESIDUAL_FLOOR_M**2)  # outliers do not widen it
            refreshed = residuals <= bound * robust_variance
            if refreshed.sum() < MIN_PAIRS or np.array_equal(refreshed, inliers):
                break
            inliers = refreshed
        else:  # the last round's pairs, fitted
            similarity = umeyama(source[inliers], target[inliers], with_scale=True)
            variance = float(np.mean(np.sum((similarity.apply(source[inliers]) - target[inliers]) ** 2, axis=1))) / 3.0
        span = float(times[inliers].max() - times[inliers].min())
        independent = max(1.0, span / correlation_time_s)
        covariance = _fit_covariance(similarity.scale, similarity.rotation, source[inliers], variance, independent)
        return MapFit(
            similarity.scale,
            similarity.rotation,
            similarity.translation,
            covariance,
            int(inliers.sum()),
            int((~inliers).sum()),
            math.sqrt(3.0 * variance),
            span,
        )


def _fit_covariance(scale: float, R: np.ndarray, source: np.ndarray, variance: float, independent: float) -> np.ndarray:
    """Linear least-squares covariance of (log scale, world rotation error, translation) for
    ``world = exp(log_scale) Exp(dtheta) R @ map + t``, each pair weighed by ``variance`` per
    axis and the pairs counted as ``independent`` observations."""
    mapped = scale * source @ R.T  # s R p, the rotated and scaled map points
    n = len(source)
    J = np.zeros((3 * n, 7))
    J[:, 0] = mapped.reshape(-1)
    J[:, 1:4] = -skew(mapped).reshape(3 * n, 3)
    J[:, 4:7] = np.tile(np.eye(3), (n, 1))
    information = J.T @ J / variance * (independent / n)
    return np.linalg.inv(information)
