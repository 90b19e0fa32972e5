"""The alignment phase of seed 002: visual odometry mapped onto GPS (ENU at take-off).

Pairs (P_odom, P_gps) are collected over a window after the target altitude is reached (or over a
given first fraction of the fixes), the camera-vs-GPS clock offset is estimated, pairs are filtered
by height and speed (relaxed adaptively when too few remain), and the transform model and RANSAC
threshold are chosen by a grid search scored on a held-out, later part of the window; a window too
short to hold pairs out (a survey of a few photos) is fitted on all its pairs with default settings
instead, with a warning. The chosen transform then maps every later visual position; the altitude
comes from the barometer.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass, field

import numpy as np

from evp.config import AlignmentSettings
from evp.fusion.gps_input import AlignmentError, GpsTrack
from evp.fusion.odometry_to_enu import MODELS, OdomToEnu, fit_transform
from evp.geometry.alignment import umeyama
from evp.types import Trajectory

ABSOLUTE_MIN_PAIRS = 6  # below this no alignment is attempted (a 3-D affine needs 4, plus validation)
MIN_VALIDATION_PAIRS = 3  # fewer held-out pairs cannot rank the grid: the fit then uses every pair (default_fit)


@dataclass
class AlignmentResult:
    transform: OdomToEnu
    clock_offset_s: float  # GPS clock minus camera clock
    window: tuple[float, float]  # GPS-clock times of the alignment phase
    pairs_used: int
    validation_rmse_m: float | None  # None: too few pairs to hold some out (fitted on all, default settings)
    chosen: dict
    aligned: Trajectory  # ENU positions at the odometry (camera) times
    warnings: list[str] = field(default_factory=list)


def resample(trajectory: Trajectory, times: np.ndarray, max_gap_s: float) -> tuple[np.ndarray, np.ndarray]:
    """Positions linearly interpolated at ``times``; mask of times inside the track and not in a gap."""
    stamps = trajectory.timestamps
    index = np.searchsorted(stamps, times)
    inside = (index > 0) & (index < len(stamps))
    lo = np.clip(index - 1, 0, len(stamps) - 1)
    hi = np.clip(index, 0, len(stamps) - 1)
    exact = np.isclose(times, stamps[hi])
    ok = (inside & (stamps[hi] - stamps[lo] <= max_gap_s)) | exact
    span = np.where(stamps[hi] > stamps[lo], stamps[hi] - stamps[lo], 1.0)
    w = np.clip((times - stamps[lo]) / span, 0.0, 1.0)[:, None]
    positions = (1 - w) * trajectory.positions[lo] + w * trajectory.positions[hi]
    return positions, ok


def _nearly_collinear(points: np.ndarray, ratio: float = 0.1) -> bool:
    """True when the points spread along one direction only (second singular value < ratio x first)."""
    if len(points) < 3:
        return True
    singular = np.linalg.svd(points - points.mean(axis=0), compute_uv=False)
    return bool(singular[1] < ratio * singular[0])


def _affine_unconstrained(points: np.ndarray, mode: str, ratio: float = 0.1) -> bool:
    """True when the pairs are nearly coplanar (3-D) or collinear (2-D), leaving an affine free."""
    used = points if mode == "3d+baro" else points[:, :2]
    singular = np.linalg.svd(used - used.mean(axis=0), compute_uv=False)
    return bool(singular[-1] < ratio * singular[0])


def estimate_clock_offset(odom: Trajectory, gps: GpsTrack, max_offset_s: float, max_gap_s: float) -> float:
    """The offset (GPS clock minus camera clock) whose pairs a similarity fits best (coarse grid, then
    a parabola through the best three)."""
    if max_offset_s == 0:
        return 0.0
    candidates = np.arange(-max_offset_s, max_offset_s + 1e-9, 0.05)

    def residual(offset: float) -> float:
        positions, ok = resample(odom, gps.times - offset, max_gap_s)
        if ok.sum() < 6:
            return np.inf
        try:
            fit = umeyama(positions[ok], gps.enu[ok], with_scale=True)
        except Exception:  # degenerate: no motion in this window
            return np.inf
        return float(np.sqrt(np.mean(np.sum((fit.apply(positions[ok]) - gps.enu[ok]) ** 2, axis=1))))

    costs = np.array([residual(c) for c in candidates])
    if not np.isfinite(costs).any():
        raise AlignmentError("cannot estimate the clock offset: the odometry and GPS do not overlap in time")
    best = int(np.argmin(costs))
    if 0 < best < len(candidates) - 1 and np.all(np.isfinite(costs[best - 1 : best + 2])):
        c0, c1, c2 = costs[best - 1 : best + 2]
        curvature = c0 - 2 * c1 + c2
        if curvature > 0:
            return float(candidates[best] + 0.5 * 0.05 * (c0 - c2) / curvature)
    return float(candidates[best])


def _speeds(gps: GpsTrack) -> np.ndarray:
    velocity = np.gradient(gps.enu[:, :2], gps.times, axis=0) if len(gps) > 1 else np.zeros((len(gps), 2))
    return np.linalg.norm(velocity, axis=1)


def alignment_window(gps: GpsTrack, settings: AlignmentSettings, align_fraction: float | None) -> tuple[float, float, float]:
    """(start, end, target altitude) of the alignment phase on the GPS clock."""
    target = settings.target_altitude_m if settings.target_altitude_m is not None else float(np.percentile(gps.enu[:, 2], 90))
    if align_fraction is not None:
        if not 0 < align_fraction < 1:
            raise AlignmentError(f"--align-fraction must be between 0 and 1, got {align_fraction}")
        count = max(ABSOLUTE_MIN_PAIRS, int(round(align_fraction * len(gps))))
        if count >= len(gps):
            raise AlignmentError(f"aligning on {count} of {len(gps)} fixes leaves none to evaluate")
        return float(gps.times[0]), float(gps.times[count - 1]), target
    reached = np.flatnonzero(np.abs(gps.enu[:, 2] - target) <= settings.altitude_tolerance_m)
    if len(reached) == 0:
        raise AlignmentError(f"the flight never reaches the target altitude {target:.1f} m (+-{settings.altitude_tolerance_m} m)")
    start = float(gps.times[reached[0]])
    return start, start + settings.window_s, target


def align_flight(
    odom: Trajectory, gps: GpsTrack, baro_up: Trajectory | None, settings: AlignmentSettings, align_fraction: float | None = None
) -> AlignmentResult:
    """Run the alignment phase and map the whole visual track to ENU.

    ``baro_up`` holds barometric heights above take-off (its x and y unused) on the camera clock.
    """
    if odom.timestamps is None or len(odom) < ABSOLUTE_MIN_PAIRS:
        raise AlignmentError(f"the visual track has {len(odom)} poses; at least {ABSOLUTE_MIN_PAIRS} are needed to align")
    if settings.mode == "2d+baro" and baro_up is None:
        raise AlignmentError("2d+baro alignment needs barometer heights; use 3d+baro")
    warnings = list(gps.warnings)
    start, end, target = alignment_window(gps, settings, align_fraction)
    if _nearly_collinear(gps.enu[(gps.times >= start) & (gps.times <= end)]) and start > gps.times[0]:
        # a straight leg leaves the rotation about it free: take the climb too (it is vertical)
        warnings.append(f"the alignment window ({start:.1f}-{end:.1f} s) is a nearly straight path: extended back to the first fix")
        start = float(gps.times[0])
    in_window = (gps.times >= start) & (gps.times <= end)
    window = gps.select(in_window)
    offset = estimate_clock_offset(odom, window, settings.max_clock_offset_s, settings.max_gap_s)
    odom_at_gps, ok = resample(odom, window.times - offset, settings.max_gap_s)
    if ok.sum() < ABSOLUTE_MIN_PAIRS:
        raise AlignmentError(f"only {int(ok.sum())} GPS fixes of the alignment phase have a visual position; at least {ABSOLUTE_MIN_PAIRS} are needed")
    pairs_odom, pairs_gps, pair_times = odom_at_gps[ok], window.enu[ok], window.times[ok]
    speeds = _speeds(window)[ok]
    heights = np.abs(pairs_gps[:, 2] - target)
    split = pair_times[0] + (1 - settings.validation_fraction) * (pair_times[-1] - pair_times[0])
    train, validate = pair_times <= split, pair_times > split
    models = MODELS if settings.model == "auto" else (settings.model,)
    if "affine" in models and _affine_unconstrained(pairs_gps, settings.mode):
        # an affine map has a free stretch across a flat (3-D) or straight (2-D) set of pairs
        warnings.append("the alignment pairs do not span enough directions for an affine fit: similarity used")
        models = ("similarity",)
    if validate.sum() < MIN_VALIDATION_PAIRS:
        rmse, params = None, default_fit(models, settings)
        warnings.append(
            f"the alignment phase has {len(pair_times)} pairs, too few to hold {MIN_VALIDATION_PAIRS} out for validation: "
            f"fitted on all of them with the default settings ({params['model']}, the grid's widest RANSAC threshold "
            f"{params['ransac_threshold_m']:g} m and height and speed filters), not validated"
        )
    else:
        rmse, params = _grid_search(pairs_odom, pairs_gps, heights, speeds, train, validate, models, settings)
    keep = (heights <= params["height_tolerance_m"]) & (speeds <= params["max_speed_m_s"])
    transform, inliers = fit_transform(pairs_odom[keep], pairs_gps[keep], settings.mode, params["model"], params["ransac_threshold_m"])
    if inliers.sum() < max(4, 0.3 * keep.sum()):
        warnings.append(f"only {int(inliers.sum())} of {int(keep.sum())} pairs are RANSAC inliers: the alignment may be poor")
    baro = None
    if baro_up is not None:
        baro = np.interp(odom.timestamps, baro_up.timestamps, baro_up.positions[:, 2])
    elif settings.mode == "3d+baro":
        warnings.append("no barometer: the altitude comes from the 3-D transform of the visual track")
    aligned_positions = transform.apply(odom.positions, baro)
    aligned = Trajectory(aligned_positions, np.tile([0.0, 0.0, 0.0, 1.0], (len(odom), 1)), odom.timestamps.copy(), "aligned_enu")
    return AlignmentResult(transform, offset, (start, end), int(keep.sum()), rmse, params | {"target_altitude_m": target}, aligned, warnings)


def default_fit(models: tuple[str, ...], settings: AlignmentSettings) -> dict:
    """The settings of a fit that cannot be validated: the simplest allowed model (a similarity
    has 7 degrees of freedom, a 3-D affine 12, which a handful of pairs cannot pin down) and the
    grid's least selective filters (a few pairs cannot spare any on evidence they cannot check)."""
    return {
        "model": "similarity" if "similarity" in models else models[0],
        "ransac_threshold_m": max(settings.ransac_thresholds_m),
        "height_tolerance_m": max(settings.height_tolerances_m),
        "max_speed_m_s": max(settings.max_speeds_m_s),
    }


def _grid_search(
    pairs_odom: np.ndarray,
    pairs_gps: np.ndarray,
    heights: np.ndarray,
    speeds: np.ndarray,
    train: np.ndarray,
    validate: np.ndarray,
    models: tuple[str, ...],
    settings: AlignmentSettings,
) -> tuple[float, dict]:
    """(validation RMSE, settings) of the grid point that fits the training pairs best as scored on the held-out ones."""
    required = min(settings.min_pairs, int(train.sum()))  # filters may not leave fewer (the unfiltered set always qualifies)
    best: tuple[float, dict] | None = None
    for model, threshold, height_tol, max_speed in itertools.product(
        models, settings.ransac_thresholds_m, settings.height_tolerances_m, settings.max_speeds_m_s
    ):
        chosen = train & (heights <= height_tol) & (speeds <= max_speed)
        if chosen.sum() < required:
            continue  # this filter is too aggressive here: adaptively skipped
        try:
            transform, _ = fit_transform(pairs_odom[chosen], pairs_gps[chosen], settings.mode, model, threshold)
        except AlignmentError:
            continue
        predicted = transform.apply(pairs_odom[validate])
        rmse = float(np.sqrt(np.mean(np.sum((predicted[:, :2] - pairs_gps[validate, :2]) ** 2, axis=1))))
        params = {"model": model, "ransac_threshold_m": threshold, "height_tolerance_m": height_tol, "max_speed_m_s": max_speed}
        if best is None or rmse < best[0]:
            best = (rmse, params)
    if best is None:
        raise AlignmentError(f"no transform could be fitted to the {int(train.sum())} training pairs (RANSAC failed under every setting of the grid)")
    return best


def horizontal_errors_after(result: AlignmentResult, gps: GpsTrack, max_gap_s: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """Horizontal error (m) of the aligned track at each GPS fix after the alignment phase, and the
    GPS up (m) of those fixes (for near-target-altitude subsets)."""
    after = gps.times > result.window[1]
    aligned, ok = resample(result.aligned, gps.times[after] - result.clock_offset_s, max_gap_s)
    errors = np.linalg.norm(aligned[ok, :2] - gps.enu[after][ok, :2], axis=1)
    return errors, gps.enu[after][ok, 2]
