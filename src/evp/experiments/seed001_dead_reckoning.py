"""Seed 001's Figure 3: the robot's position from the phone's accelerometer integrated twice
against its wheel encoders (with the gyro's yaw rate, and with the wheels' own differential
turn rate), on the simulated wheel-robot room (``evp sim wheel-robot-room``'s motion and sensor
models, sampled without rendering images; seeds 1-3).

The accelerometer path is a strapdown integration (``fusion.strapdown``) started from the true
pose and velocity, biases unknown (zero), as a phone would have to; the wheel paths use the
EKF-SLAM's motion model (``fusion.planar_motion``) from the true start. The paper found the
accelerometer's drift too large for a slow robot ("the low cost accelerometers produce large
position drift"); the encoders followed the path.

The same on the real comma2k19 segment (``$EVP_SHARED_DATA/comma2k19_example_segment_sensors``:
a phone-class IMU in a car on a highway, CAN wheel speeds, the INS/GNSS truth; 60 s, 1 km). Its
IMU axes are the device's (forward, right, down) and the truth's attitude is the device's too
(its README; the TUM file turns it into the optical camera frame, undone here), so the
strapdown starts from the truth's attitude and velocity; the wheel paths from the direction of
that velocity (the phone sits 0.8 deg off the car's axis: 14 m across over the 1 km). The wheel paths use the mean of the four
wheel speeds; their turn rate is the gyro's about the vertical (``fusion.wheel_gyro``), or the
rear wheels' difference over the car's track (``CAR_REAR_TRACK_M``). A missing folder is said in
the report, not an error.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from evp.experiments.series import value_at  # noqa: E402
from evp.experiments.shared_data import shared_data_folder  # noqa: E402
from evp.fusion.nav_state import NavState  # noqa: E402
from evp.fusion.planar_motion import dead_reckoning  # noqa: E402
from evp.fusion.strapdown import strapdown_step  # noqa: E402
from evp.sim.motion import GRAVITY_M_S2  # noqa: E402
from evp.sim.scenarios import SimOptions, wheel_robot_room  # noqa: E402
from evp.sim.sensors import sample_times, simulate_imu, simulate_wheels  # noqa: E402

SEEDS = (1, 2, 3)
METHODS = ("accelerometer (strapdown)", "wheels + gyro", "wheels alone (differential turn rate)")
COMMA_FOLDER = "comma2k19_example_segment_sensors"
# The rear track of the comma2k19 car: the segment does not name the model; 1.6 m is a mid-size
# car's (Toyota RAV4 1.62 m, Honda Civic 1.56 m, Prius 1.54 m); a 3 % error scales the turn rate
# by 3 %.
CAR_REAR_TRACK_M = 1.6
# the optical camera axes (x right, y down, z forward) in the device frame (forward, right, down)
R_DEVICE_OPTICAL = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])


def paths_for_seed(seed: int) -> tuple[np.ndarray, dict[str, tuple[np.ndarray, np.ndarray]]]:
    """The truth's (times, x, y) at the IMU rate and each method's (times, xy)."""
    options = SimOptions(seed=seed)
    scenario = wheel_robot_room(options)
    start, end = scenario.motion.start, scenario.motion.end
    imu_state = scenario.motion.state(sample_times(start, end, options.imu.rate_hz))
    imu = simulate_imu(imu_state, options.imu, np.random.default_rng([seed, 1])).samples
    wheel_state = scenario.motion.state(sample_times(start, end, options.wheel.rate_hz))
    wheels = simulate_wheels(wheel_state, options.wheel, np.random.default_rng([seed, 2]))
    accel = strapdown_path(imu, NavState(imu[0].timestamp, imu_state.position[0].copy(), imu_state.velocity[0].copy(), imu_state.rotation[0].as_matrix()))
    times = np.array([w.timestamp for w in wheels])
    start_pose = (*wheel_state.position[0, :2], float(wheel_state.rotation[0].as_euler("ZYX")[0]))
    speeds = np.array([w.forward_speed_m_s for w in wheels])
    gyro = np.array([w.yaw_rate_rad_s for w in wheels])
    differential = np.array([(w.wheel_speeds_m_s[1] - w.wheel_speeds_m_s[0]) / options.wheel.wheel_base_m for w in wheels])
    truth = np.column_stack([imu_state.time, imu_state.position[:, :2]])
    imu_times = np.array([s.timestamp for s in imu])
    return truth, {
        METHODS[0]: (imu_times, accel),
        METHODS[1]: (times, dead_reckoning(start_pose, times, speeds, gyro)[:, :2]),
        METHODS[2]: (times, dead_reckoning(start_pose, times, speeds, differential)[:, :2]),
    }


def strapdown_path(imu: list, start: NavState) -> np.ndarray:
    """(N, 2) horizontal positions of the accelerometer integrated twice from ``start``."""
    nav, path = start, [start.position[:2]]
    for previous, current in zip(imu, imu[1:]):
        nav, _ = strapdown_step(nav, previous, current, GRAVITY_M_S2)
        path.append(nav.position[:2])
    return np.array(path)


def comma_paths(folder: Path) -> tuple[np.ndarray, dict[str, tuple[np.ndarray, np.ndarray]]]:
    """The comma2k19 segment: the truth's (times, x, y) in ENU and each method's (times, xy),
    all started at the first IMU sample inside the truth's span, from the truth there."""
    from evp.fusion.wheel_gyro import with_gyro_yaw_rate
    from evp.io.registry import open_dataset

    dataset = open_dataset(folder)
    truth = dataset.ground_truth
    t0 = max(truth.timestamps[0], dataset.imu[0].timestamp, dataset.wheel[0].timestamp)
    imu = [s for s in dataset.imu if t0 <= s.timestamp <= truth.timestamps[-1]]
    wheel = [w for w in dataset.wheel if imu[0].timestamp <= w.timestamp <= imu[-1].timestamp]
    start = imu[0].timestamp
    position = np.array([np.interp(start, truth.timestamps, truth.positions[:, k]) for k in range(3)])
    after = int(np.searchsorted(truth.timestamps, start))
    velocity = (truth.positions[after + 1] - truth.positions[after - 1]) / (truth.timestamps[after + 1] - truth.timestamps[after - 1])
    R_world_device = truth.poses[after, :3, :3] @ R_DEVICE_OPTICAL.T
    accelerometer = strapdown_path(imu, NavState(start, position, velocity, R_world_device))
    gyro = with_gyro_yaw_rate(wheel, imu)
    times = np.array([start, *(w.timestamp for w in wheel)])
    speeds = np.array([0.0, *(w.forward_speed_m_s for w in wheel)])
    turn_gyro = np.nan_to_num(np.array([0.0, *(w.yaw_rate_rad_s for w in gyro)]))  # outside the IMU's span: no turn
    turn_wheels = np.array([0.0, *((w.wheel_speeds_m_s[3] - w.wheel_speeds_m_s[2]) / CAR_REAR_TRACK_M for w in wheel)])
    heading = float(np.arctan2(velocity[1], velocity[0]))  # the car's, not the device's: the phone sits 0.8 deg off its axis
    start_pose = (position[0], position[1], heading)
    return np.column_stack([truth.timestamps, truth.positions[:, :2]]), {
        METHODS[0]: (np.array([s.timestamp for s in imu]), accelerometer),
        METHODS[1]: (times, dead_reckoning(start_pose, times, speeds, turn_gyro)[:, :2]),
        METHODS[2]: (times, dead_reckoning(start_pose, times, speeds, turn_wheels)[:, :2]),
    }


def _errors(truth: np.ndarray, times: np.ndarray, xy: np.ndarray) -> np.ndarray:
    reference = np.column_stack([np.interp(times, truth[:, 0], truth[:, k]) for k in (1, 2)])
    return np.linalg.norm(xy - reference, axis=1)


def run(out: Path, progress: Callable[[str], None] = lambda text: None) -> Path:
    out.mkdir(parents=True, exist_ok=True)
    rows, plots, notes = [], [], []
    cases = [(f"seed {seed}", f"seed{seed}", lambda seed=seed: paths_for_seed(seed)) for seed in SEEDS]
    comma = shared_data_folder(COMMA_FOLDER)
    if comma.is_dir():
        cases.append(("comma2k19", "comma2k19", lambda: comma_paths(comma)))
    else:
        notes.append(f"comma2k19: {comma} is missing; the real segment was not run.")
    for label, slug, paths_of in cases:
        progress(label)
        truth, paths = paths_of()
        fig, (top, over_time) = plt.subplots(1, 2, figsize=(12, 4.8))
        top.plot(truth[:, 1], truth[:, 2], "--", color="0.4", label="truth")
        for name, (times, xy) in paths.items():
            errors = _errors(truth, times, xy)
            elapsed = times - times[0]
            rows.append(
                f"| {label} | {name} | {value_at(elapsed, errors, 10.0):.2f} | {value_at(elapsed, errors, 30.0):.2f} | {errors[-1]:.2f} | {elapsed[-1]:.0f} |"
            )
            extent = np.linalg.norm(truth[:, 1:] - truth[0, 1:], axis=1).max() + 10.0
            shown = np.linalg.norm(xy - truth[0, 1:], axis=1) < extent  # the accelerometer leaves: keep the view on the path
            top.plot(xy[shown, 0], xy[shown, 1], lw=0.9, label=name)
            over_time.semilogy(times - times[0], np.maximum(errors, 1e-4), lw=0.9, label=name)
        top.set_aspect("equal", adjustable="datalim")
        top.set(xlabel="x (m)", ylabel="y (m)", title=f"{label}: top view (within 10 m of the path's extent)")
        over_time.set(xlabel="time (s)", ylabel="position error (m)", title=f"{label}: error against the truth")
        for ax in (top, over_time):
            ax.grid(alpha=0.3, which="both")
            ax.legend(fontsize=8)
        fig.tight_layout()
        name = f"dead_reckoning_{slug}.png"
        fig.savefig(out / name, dpi=110)
        plt.close(fig)
        plots.append(name)
    report = "\n".join(
        [
            "# Seed 001: accelerometer against wheel encoders (Figure 3)",
            "",
            (__doc__ or "").split("\n\n", 1)[1].strip(),
            "",
            "| run | method | error at 10 s (m) | at 30 s (m) | at the end (m) | end (s) |",
            "|---|---|---|---|---|---|",
            *rows,
            "",
            *notes,
            "",
            *[f"![{p}]({p})" for p in plots],
            "",
        ]
    )
    path = out / "report.md"
    path.write_text(report)
    return path
