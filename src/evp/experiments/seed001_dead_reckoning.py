"""Seed 001's Figure 3: the robot's position from the phone's accelerometer integrated twice
against its wheel encoders (with the gyro's yaw rate, and with the wheels' own differential
turn rate), on the simulated wheel-robot room (``evp sim wheel-robot-room``'s motion and sensor
models, sampled without rendering images; seeds 1-3).

The accelerometer path is a strapdown integration (``fusion.strapdown``) started from the true
pose and velocity, biases unknown (zero), as a phone would have to; the wheel paths use the
EKF-SLAM's motion model (``fusion.planar_motion``) from the true start. The paper found the
accelerometer's drift too large for a slow robot ("the low cost accelerometers produce large
position drift"); the encoders followed the path.

Not done yet: the same on the real comma2k19 segment (its IMU is in the device frame and the
truth in the camera's, so the mounting must be estimated first).
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from evp.experiments.series import value_at  # noqa: E402
from evp.fusion.nav_state import NavState  # noqa: E402
from evp.fusion.planar_motion import dead_reckoning  # noqa: E402
from evp.fusion.strapdown import strapdown_step  # noqa: E402
from evp.sim.motion import GRAVITY_M_S2  # noqa: E402
from evp.sim.scenarios import SimOptions, wheel_robot_room  # noqa: E402
from evp.sim.sensors import sample_times, simulate_imu, simulate_wheels  # noqa: E402

SEEDS = (1, 2, 3)
METHODS = ("accelerometer (strapdown)", "wheels + gyro", "wheels alone (differential turn rate)")


def paths_for_seed(seed: int) -> tuple[np.ndarray, dict[str, tuple[np.ndarray, np.ndarray]]]:
    """The truth's (times, x, y) at the IMU rate and each method's (times, xy)."""
    options = SimOptions(seed=seed)
    scenario = wheel_robot_room(options)
    start, end = scenario.motion.start, scenario.motion.end
    imu_state = scenario.motion.state(sample_times(start, end, options.imu.rate_hz))
    imu = simulate_imu(imu_state, options.imu, np.random.default_rng([seed, 1])).samples
    wheel_state = scenario.motion.state(sample_times(start, end, options.wheel.rate_hz))
    wheels = simulate_wheels(wheel_state, options.wheel, np.random.default_rng([seed, 2]))
    nav = NavState(imu[0].timestamp, imu_state.position[0].copy(), imu_state.velocity[0].copy(), imu_state.rotation[0].as_matrix())
    accel = [nav.position[:2]]
    for previous, current in zip(imu, imu[1:]):
        nav, _ = strapdown_step(nav, previous, current, GRAVITY_M_S2)
        accel.append(nav.position[:2])
    times = np.array([w.timestamp for w in wheels])
    start_pose = (*wheel_state.position[0, :2], float(wheel_state.rotation[0].as_euler("ZYX")[0]))
    speeds = np.array([w.forward_speed_m_s for w in wheels])
    gyro = np.array([w.yaw_rate_rad_s for w in wheels])
    differential = np.array([(w.wheel_speeds_m_s[1] - w.wheel_speeds_m_s[0]) / options.wheel.wheel_base_m for w in wheels])
    truth = np.column_stack([imu_state.time, imu_state.position[:, :2]])
    imu_times = np.array([s.timestamp for s in imu])
    return truth, {
        METHODS[0]: (imu_times, np.array(accel)),
        METHODS[1]: (times, dead_reckoning(start_pose, times, speeds, gyro)[:, :2]),
        METHODS[2]: (times, dead_reckoning(start_pose, times, speeds, differential)[:, :2]),
    }


def _errors(truth: np.ndarray, times: np.ndarray, xy: np.ndarray) -> np.ndarray:
    reference = np.column_stack([np.interp(times, truth[:, 0], truth[:, k]) for k in (1, 2)])
    return np.linalg.norm(xy - reference, axis=1)


def run(out: Path, progress: Callable[[str], None] = lambda text: None) -> Path:
    out.mkdir(parents=True, exist_ok=True)
    rows, plots = [], []
    for seed in SEEDS:
        progress(f"seed {seed}")
        truth, paths = paths_for_seed(seed)
        fig, (top, over_time) = plt.subplots(1, 2, figsize=(12, 4.8))
        top.plot(truth[:, 1], truth[:, 2], "--", color="0.4", label="truth")
        for name, (times, xy) in paths.items():
            errors = _errors(truth, times, xy)
            elapsed = times - times[0]
            rows.append(
                f"| {seed} | {name} | {100 * value_at(elapsed, errors, 10.0):.1f} | {100 * value_at(elapsed, errors, 30.0):.1f} | {100 * errors[-1]:.1f} |"
            )
            shown = np.linalg.norm(xy - truth[0, 1:], axis=1) < 10.0  # the accelerometer leaves the room: keep the view on it
            top.plot(xy[shown, 0], xy[shown, 1], lw=0.9, label=name)
            over_time.semilogy(times - times[0], np.maximum(errors, 1e-4), lw=0.9, label=name)
        top.set_aspect("equal", adjustable="datalim")
        top.set(xlabel="x (m)", ylabel="y (m)", title=f"seed {seed}: top view (within 10 m of the start)")
        over_time.set(xlabel="time (s)", ylabel="position error (m)", title=f"seed {seed}: error against the truth")
        for ax in (top, over_time):
            ax.grid(alpha=0.3, which="both")
            ax.legend(fontsize=8)
        fig.tight_layout()
        name = f"dead_reckoning_seed{seed}.png"
        fig.savefig(out / name, dpi=110)
        plt.close(fig)
        plots.append(name)
    report = "\n".join(
        [
            "# Seed 001: accelerometer against wheel encoders (Figure 3)",
            "",
            (__doc__ or "").split("\n\n", 1)[1].strip(),
            "",
            "| seed | method | error at 10 s (cm) | at 30 s (cm) | at the end, 60 s (cm) |",
            "|---|---|---|---|---|",
            *rows,
            "",
            *[f"![{p}]({p})" for p in plots],
            "",
        ]
    )
    path = out / "report.md"
    path.write_text(report)
    return path
