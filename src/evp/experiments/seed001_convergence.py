"""Seed 001's convergence study (its Figures 9-12) with EVP's EKF-SLAM on exact synthetic data.

The paper ran its filter on hand-picked features whose first guesses it chose: the robot's start
position and heading, and each feature's first position, azimuth, elevation and inverse depth.
Here a robot drives twice round a 1 m circle inside a ring of 24 points (``sim.landmark_drive``),
its wheels exact but its gyro biased by 0.002 rad/s (the rendered robot's), and every point is in
the state from the start, as the paper's surveyed features were. Four cases:

1. true initial states (Fig. 9): the paper's errors stay under 3 cm;
2. the robot's start 0.40 m and 0.15 rad off (Fig. 10): the paper's converge from 35-50 cm to
   under 3 cm;
3. every feature's first guess off: anchor 0.2 m, azimuth and elevation 0.1 rad, inverse depth
   x1.5 (Fig. 11): the paper's converge slowly (still > 30 cm at its end);
4. all of them (Fig. 12).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from evp.config import EkfSlamSettings  # noqa: E402
from evp.ekf_slam.filter import EkfSlamFilter, yaw_rotation  # noqa: E402
from evp.ekf_slam.inverse_depth import ray_angles  # noqa: E402
from evp.ekf_slam.known_features import NO_DESCRIPTOR, run_known_features  # noqa: E402
from evp.experiments.series import value_at  # noqa: E402
from evp.sim.landmark_drive import CAMERA_OFFSET, FORWARD_CAMERA, ring_loop  # noqa: E402

GYRO_BIAS_RAD_S = 0.002  # the rendered robot's (sim WheelConfig.gyro_bias_rad_s)
START_ERROR = (0.32, -0.24, 0.15)  # x, y (0.40 m), heading (rad): the paper's 35-50 cm
START_SIGMA = (0.5, 0.2)  # the filter's belief: 0.5 m, 0.2 rad
FEATURE_ERROR = (0.2, 0.1, 1.5)  # anchor (m, along a fixed direction), angles (rad), inverse-depth factor
FEATURE_SIGMA = (0.3, 0.15, 0.3)  # the filter's belief in a first guess: anchor m, angles rad, inverse depth 1/m
TRUE_SIGMA = (0.01, 0.005, 0.01)  # a surveyed feature's
CASES = {
    "true initial states (Fig. 9)": (False, False),
    "robot start off (Fig. 10)": (True, False),
    "features off (Fig. 11)": (False, True),
    "all off (Fig. 12)": (True, True),
}


@dataclass(frozen=True)
class CaseResult:
    name: str
    times: np.ndarray
    position_error: np.ndarray  # per wheel sample (m)
    heading_error: np.ndarray  # per wheel sample (rad)
    frame_times: np.ndarray
    feature_error: np.ndarray  # per frame, mean over the points (m)


def _feature_guess(point: np.ndarray, anchor: np.ndarray, wrong: bool) -> tuple[np.ndarray, np.ndarray]:
    azimuth, elevation, _ = ray_angles(point - anchor)
    values = np.array([*anchor, azimuth, elevation, 1.0 / np.linalg.norm(point - anchor)])
    sigma = FEATURE_SIGMA if wrong else TRUE_SIGMA
    if wrong:
        anchor_error, angle_error, depth_factor = FEATURE_ERROR
        values += [anchor_error / np.sqrt(2), -anchor_error / np.sqrt(2), 0.0, angle_error, -angle_error, 0.0]
        values[5] *= depth_factor
    anchor_sigma, angle_sigma, rho_sigma = sigma
    return values, np.diag([anchor_sigma**2] * 3 + [angle_sigma**2] * 2 + [rho_sigma**2])


def run_case(name: str, robot_off: bool, features_off: bool) -> CaseResult:
    scene = ring_loop()
    flt = EkfSlamFilter(FORWARD_CAMERA, CAMERA_OFFSET, EkfSlamSettings(max_features=len(scene.points)), 500.0)
    if robot_off:
        flt.set_start(*START_ERROR, *START_SIGMA)
    anchor = yaw_rotation(0.0) @ CAMERA_OFFSET  # the true camera centre at the start
    given = {}
    for index, point in enumerate(scene.points):
        values, covariance = _feature_guess(point, anchor, features_off)
        given[index] = flt.add_feature_state(values, covariance, NO_DESCRIPTOR, 0.0).id
    run = run_known_features(
        flt, scene.times, scene.speeds, scene.yaw_rates + GYRO_BIAS_RAD_S, 5, scene.bearings, len(scene.points), len(scene.points), given=given
    )
    position_error = np.linalg.norm(run.poses[:, :2] - scene.poses[:, :2], axis=1)
    heading_error = np.abs(np.angle(np.exp(1j * (run.poses[:, 2] - scene.poses[:, 2]))))
    feature_error = np.nanmean(np.linalg.norm(run.feature_points - scene.points[None], axis=2), axis=1)
    return CaseResult(name, scene.times, position_error, heading_error, run.frame_times, feature_error)


def _plot(results: list[CaseResult], out: Path) -> list[str]:
    names = []
    fig, (robot, features) = plt.subplots(1, 2, figsize=(12, 4.5))
    for r in results:
        robot.semilogy(r.times, np.maximum(r.position_error, 1e-4), lw=1.0, label=r.name)
        features.semilogy(r.frame_times, np.maximum(r.feature_error, 1e-4), lw=1.0, label=r.name)
    robot.axhline(0.03, color="0.4", ls="--", lw=0.8, label="3 cm (the paper's converged error)")
    robot.set(xlabel="time (s)", ylabel="robot position error (m)", title="Robot position error (Figs. 9-12)")
    features.set(xlabel="time (s)", ylabel="mean feature position error (m)", title="Feature position error")
    for ax in (robot, features):
        ax.grid(alpha=0.3, which="both")
        ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(out / "convergence.png", dpi=110)
    plt.close(fig)
    names.append("convergence.png")
    return names


def run(out: Path, progress: Callable[[str], None] = lambda text: None) -> Path:
    out.mkdir(parents=True, exist_ok=True)
    results = []
    for name, (robot_off, features_off) in CASES.items():
        progress(name)
        results.append(run_case(name, robot_off, features_off))
    plots = _plot(results, out)
    start = {name: 100 * np.hypot(*START_ERROR[:2]) if robot_off else 0.0 for name, (robot_off, _) in CASES.items()}
    rows = [
        f"| {r.name} | {start[r.name]:.0f} | {100 * r.position_error[0]:.1f} | {100 * value_at(r.times, r.position_error, 5.0):.1f} | {100 * value_at(r.times, r.position_error, 20.0):.1f} | "
        f"{100 * r.position_error[-1]:.1f} | {100 * r.feature_error[0]:.1f} | {100 * r.feature_error[-1]:.1f} | {np.degrees(r.heading_error[-1]):.2f} |"
        for r in results
    ]
    duration = results[0].times[-1]
    report = "\n".join(
        [
            "# Seed 001: EKF-SLAM convergence (Figures 9-12)",
            "",
            (__doc__ or "").split("\n\n", 1)[1].strip(),
            "",
            f"Drive: {duration:.0f} s, two laps; a frame every 0.1 s; exact bearings (features of known identity).",
            "",
            "| case | robot start error (cm) | after the first frame | at 5 s | at 20 s | at the end | features at start (cm, mean) | at the end | heading at the end (deg) |",
            "|---|---|---|---|---|---|---|---|---|",
            *rows,
            "",
            "The paper: true initial states stay under 3 cm (Fig. 9); a wrong start converges from 35-50 cm",
            "to under 3 cm (Fig. 10); wrong features converge slowly, still over 30 cm at its end (Fig. 11).",
            "",
            *[f"![{p}]({p})" for p in plots],
            "",
        ]
    )
    path = out / "report.md"
    path.write_text(report)
    return path
