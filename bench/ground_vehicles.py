"""Ground vehicles without a camera: the wheel-odometry filter (evp.fusion.odometry_filter) against
odometry alone on real recordings of ../shared/data. Issue 30's figures to beat: Plaza1 dead
reckoning 4.45 m at the end, RMSE 1.93 m, a plain EKF with the ranges and a bias fixed from the
first 60 s RMSE 1.03 m; the labyrinth's wheel integration 0.38 m at the end, RMSE 0.21 m;
comma2k19 CAN speed + gyro 6-16 m off after 30 s windows, u-blox alone mean 1.45 m.

Usage: python bench/ground_vehicles.py [--out runs/ground_vehicles] [--only plaza1 labyrinth comma2k19]

Plaza1 (cmu_plaza1_wheel_odometry) and the labyrinth (tuc_labyrinth_wheel_odometry): the filter
fuses the wheel odometry with the ranges to the surveyed beacons (range biases and the ranging
scale estimated, no value taken from the ground truth); odometry alone is the same filter fed no
ranges, i.e. the increments integrated with the heading at mid-step. Both start from the ground
truth's first position; the heading is the ground truth's first one (Plaza1) or the direction of
its first second of motion (the labyrinth, whose truth has no heading), as the dataset READMEs
measured their baselines. Errors are horizontal, at every odometry sample, against the truth
interpolated there.

comma2k19 (comma2k19_example_segment_sensors, one 60 s segment): the filter runs on CAN wheel speed
plus the gyro's rate about the vertical, with the u-blox fixes (ENU at the ground truth's origin),
from the first fix and its bearing. It starts at the first fix 20 m from the first one, heading along those two (about 2.5 s in). GNSS is
cut for a window of 30 s starting 0, 5, ... 25 s after that start (six windows) and for the
longest window the segment allows (from that start to the last fix, about 57 s; a full 60 s does
not fit in the 60 s segment): the error is at the window's end. Beside it, wheel
+ gyro dead reckoning alone over the same window, started from the true pose at the window's start.
The u-blox fixes' own error against the truth is the reference row.

Writes bench/results/ground_vehicles.json and, under --out, per dataset a top view (fused,
odometry, truth) and the error over time (PNG). Needs ../shared/data; about a minute.
"""

from __future__ import annotations

import argparse
import heapq
import math
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from results import Results  # noqa: E402
from scipy.spatial.transform import Rotation  # noqa: E402

from evp.fusion.geodesy import EnuFrame  # noqa: E402
from evp.fusion.odometry_filter import OdometryFilter, OdometryNoise, PlanarPose  # noqa: E402
from evp.fusion.wheel_gyro import with_gyro_yaw_rate  # noqa: E402
from evp.io.registry import open_dataset  # noqa: E402
from evp.types import WheelOdometry  # noqa: E402

SHARED = Path(__file__).resolve().parents[2] / "shared" / "data"

# Plaza1 noise, from the dataset README: its plain EKF's odometry noise (5 % + 0.01 m and 0.01 rad
# per 0.2 s step = 0.05 m/s and 0.05 rad/s per sample) and the range residual's MAD of 0.8 m
# (1.2 m as a Gaussian sigma). Priors: range biases 0 +- 5 m (radio antenna and cable delays of a
# few metres; the README reports +2.8 m), the ranging scale 0 +- 10 %, the odometry scale 1 +- 5 %
# (tyre wear and load); the heading comes from the odometry's own increments, no bias state.
PLAZA_NOISE = OdometryNoise(
    speed_sigma_fraction=0.05,
    speed_sigma_m_s=0.05,
    yaw_rate_sigma_rad_s=0.05,
    range_sigma_m=1.2,
    scale_sigma=0.05,
    range_bias_sigma_m=5.0,
    range_scale_sigma=0.1,
)
# Labyrinth noise, from the files themselves: wheel speed variance 1e-4 (m/s)^2 per wheel
# (0.01 m/s, so 0.007 m/s forward and 0.09 rad/s turning with the 0.0785 m half spacing) and
# range variance 0.01 m^2 (0.1 m). Priors: range biases 0 +- 0.3 m (UWB antenna delay), ranging
# scale 0 +- 10 %, wheel scale 1 +- 5 %.
LABYRINTH_NOISE = OdometryNoise(
    speed_sigma_fraction=0.0,
    speed_sigma_m_s=0.01 / math.sqrt(2),
    yaw_rate_sigma_rad_s=0.01 * math.sqrt(2) / (2 * 0.0785),
    range_sigma_m=0.1,
    scale_sigma=0.05,
    range_bias_sigma_m=0.3,
    range_scale_sigma=0.1,
)
# comma2k19 noise: CAN wheel speed 1 % + 0.05 m/s (its README: median ratio to the truth's speed
# 0.991), scale 1 +- 2 %; the phone gyro (already calibrated upstream) 0.002 rad/s per sample,
# bias 0 +- 0.005 rad/s (a calibrated MEMS gyro's residual, 0.3 deg/s) drifting 1e-4 rad/s/sqrt(s);
# u-blox 1.5 m (README: horizontal median 1.4 m against the truth).
COMMA_NOISE = OdometryNoise(
    speed_sigma_fraction=0.01,
    speed_sigma_m_s=0.05,
    yaw_rate_sigma_rad_s=0.002,
    gnss_sigma_m=1.5,
    scale_sigma=0.02,
    yaw_rate_bias_sigma_rad_s=0.005,
    yaw_rate_bias_walk_rad_s_per_sqrt_s=1e-4,
)
WINDOW_STARTS_S = (0.0, 5.0, 10.0, 15.0, 20.0, 25.0)
START_BASELINE_M = 20.0  # two fixes this far apart give the start heading within ~0.15 rad

TRACK_COLUMNS = [
    ("dataset", "{dataset}"),
    ("method", "{method}"),
    ("path (m)", "{path_m:.0f}"),
    ("RMSE (m)", "{rmse_m:.2f}"),
    ("end error (m)", "{end_m:.2f}"),
    ("max (m)", "{max_m:.2f}"),
    ("to beat", "{to_beat}"),
    ("ranges accepted", "{accepted}"),
]
WINDOW_COLUMNS = [
    ("GNSS cut", "{window_s:.1f} s"),
    ("starts (s after the filter starts)", "{starts}"),
    ("method", "{method}"),
    ("end error mean (m)", "{mean_m:.2f}"),
    ("min-max (m)", "{min_m:.2f}-{max_m:.2f}"),
    ("to beat", "{to_beat}"),
]


def run_filter(noise: OdometryNoise, start: PlanarPose, t0: float, odometry, updates=(), beacons=None, frame=None) -> tuple[OdometryFilter, np.ndarray]:
    """The filter over ``odometry`` and ``updates`` merged in time; rows (t, x, y, yaw) after each
    odometry sample."""
    flt = OdometryFilter(noise, start, t0, beacons or {}, frame)
    rows = []
    for record in heapq.merge(odometry, updates, key=lambda r: r.timestamp):
        flt.add(record)
        if isinstance(record, WheelOdometry):
            state = flt.state()
            rows.append((state.timestamp, state.x, state.y, state.yaw))
    return flt, np.array(rows)


def horizontal_errors(track: np.ndarray, truth_t: np.ndarray, truth_xy: np.ndarray) -> np.ndarray:
    inside = (track[:, 0] >= truth_t[0]) & (track[:, 0] <= truth_t[-1])
    xy = np.column_stack([np.interp(track[inside, 0], truth_t, truth_xy[:, k]) for k in (0, 1)])
    return np.linalg.norm(track[inside, 1:3] - xy, axis=1)


def track_record(name: str, method: str, track: np.ndarray, truth, to_beat: str, flt: OdometryFilter | None = None) -> dict:
    errors = horizontal_errors(track, truth.timestamps, truth.positions[:, :2])
    record = {
        "dataset": name,
        "method": method,
        "path_m": truth.path_length,
        "rmse_m": float(np.sqrt(np.mean(errors**2))),
        "end_m": float(errors[-1]),
        "max_m": float(errors.max()),
        "to_beat": to_beat,
    }
    if flt is not None and flt.innovations:
        record["accepted"] = f"{sum(i.accepted for i in flt.innovations)}/{len(flt.innovations)}"
    return record


def plot_tracks(name: str, truth, tracks: dict[str, np.ndarray], out: Path) -> None:
    fig, (top, over_time) = plt.subplots(1, 2, figsize=(12, 5))
    top.plot(truth.positions[:, 0], truth.positions[:, 1], "--", color="0.4", label="truth")
    for label, track in tracks.items():
        top.plot(track[:, 1], track[:, 2], lw=0.9, label=label)
        errors = horizontal_errors(track, truth.timestamps, truth.positions[:, :2])
        over_time.plot(track[: len(errors), 0] - truth.timestamps[0], errors, lw=0.9, label=label)
    top.set_aspect("equal", adjustable="datalim")
    top.set(xlabel="x (m)", ylabel="y (m)", title=f"{name}: top view")
    over_time.set(xlabel="time (s)", ylabel="horizontal error (m)", title=f"{name}: error against the truth")
    for ax in (top, over_time):
        ax.grid(alpha=0.3)
        ax.legend(loc="best")
    fig.tight_layout()
    out.mkdir(parents=True, exist_ok=True)
    fig.savefig(out / f"{name}.png", dpi=110)
    plt.close(fig)


def yaw_of(quat_xyzw: np.ndarray) -> float:
    return float(Rotation.from_quat(quat_xyzw).as_euler("zyx")[0])


def beacon_run(name: str, folder: str, noise: OdometryNoise, start_yaw, to_beat: tuple[str, str], table, out: Path) -> None:
    dataset = open_dataset(SHARED / folder)
    truth = dataset.ground_truth
    start = PlanarPose(*truth.positions[0, :2], start_yaw(truth))
    t0 = float(truth.timestamps[0])
    _, alone = run_filter(noise, start, t0, dataset.wheel)
    flt, fused = run_filter(noise, start, t0, dataset.wheel, dataset.beacon_ranges, dataset.beacons)
    print(table.add(track_record(name, "odometry alone", alone, truth, to_beat[0])), flush=True)
    print(table.add(track_record(name, "odometry + beacon ranges (filter)", fused, truth, to_beat[1], flt)), flush=True)
    state = flt.state()
    biases = ", ".join(f"{k} {v:+.2f}" for k, v in state.range_biases_m.items())
    print(f"  {name}: speed scale {state.speed_scale:.4f}, ranging scale {state.range_scale:+.4f}, range biases (m) {biases}; warnings {flt.warnings}")
    plot_tracks(name, truth, {"odometry alone": alone, "filter with ranges": fused}, out)


def first_motion_heading(truth, moved_m: float = 0.05, after_s: float = 1.0) -> float:
    """Heading of the truth's first second of motion (the labyrinth README's baseline start)."""
    offsets = np.linalg.norm(truth.positions[:, :2] - truth.positions[0, :2], axis=1)
    first = int(np.argmax(offsets > moved_m))
    later = int(np.searchsorted(truth.timestamps, truth.timestamps[first] + after_s))
    step = truth.positions[later, :2] - truth.positions[0, :2]
    return float(math.atan2(step[1], step[0]))


def comma_run(table, out: Path) -> None:
    dataset = open_dataset(SHARED / "comma2k19_example_segment_sensors")
    truth = dataset.ground_truth
    frame = EnuFrame(*dataset.enu_origin)
    # the truth is the camera's optical frame: forward is its z axis
    forward = Rotation.from_quat(truth.quats_xyzw).as_matrix()[:, :, 2]
    truth_yaw = np.unwrap(np.arctan2(forward[:, 1], forward[:, 0]))
    odometry = with_gyro_yaw_rate(dataset.wheel, dataset.imu)
    fixes = dataset.gps
    east_north = frame.fixes_to_enu(fixes)[:, :2]
    gnss_errors = horizontal_errors(np.column_stack([[f.timestamp for f in fixes], east_north]), truth.timestamps, truth.positions[:, :2])
    # the filter starts at the first fix START_BASELINE_M from the first one, heading along them
    index = int(np.argmax(np.linalg.norm(east_north - east_north[0], axis=1) >= START_BASELINE_M))
    first = fixes[index]
    step = east_north[index] - east_north[0]
    start = PlanarPose(*east_north[index], math.atan2(step[1], step[0]), COMMA_NOISE.gnss_sigma_m, 2 * COMMA_NOISE.gnss_sigma_m / START_BASELINE_M)
    driven = [w for w in odometry if w.timestamp > first.timestamp]
    last_fix = fixes[-1].timestamp
    windows = [(30.0, s) for s in WINDOW_STARTS_S] + [(last_fix - first.timestamp, 0.0)]
    outcomes: dict[tuple[float, str], list[float]] = {}
    plotted = {}
    for length, offset in windows:
        begin, end = first.timestamp + offset, first.timestamp + offset + length
        kept = [f for f in fixes if not (begin < f.timestamp <= end)]
        _, fused = run_filter(COMMA_NOISE, start, first.timestamp, driven, kept, frame=frame)
        k = int(np.searchsorted(truth.timestamps, begin))
        true_start = PlanarPose(*truth.positions[k, :2], float(truth_yaw[k]))
        window_odometry = [w for w in odometry if truth.timestamps[k] < w.timestamp]
        _, alone = run_filter(COMMA_NOISE, true_start, float(truth.timestamps[k]), window_odometry)
        for method, track in (("filter: wheel + gyro + u-blox, GNSS cut", fused), ("wheel + gyro dead reckoning from the true pose", alone)):
            at_end = track[track[:, 0] <= end]
            error = horizontal_errors(at_end[-1:], truth.timestamps, truth.positions[:, :2])[0]
            outcomes.setdefault((round(length, 1), method), []).append(float(error))
            if length == 30.0 and offset == WINDOW_STARTS_S[0]:
                plotted[method.split(":")[0]] = track[track[:, 0] <= end]
    for (length, method), errors in outcomes.items():
        starts = ", ".join(f"{s:.0f}" for s in WINDOW_STARTS_S) if length == 30.0 else "0"
        to_beat = ("6-16 m (CAN speed + gyro)" if "dead" in method else "< dead reckoning") if length == 30.0 else "-"
        record = {
            "window_s": length,
            "starts": starts,
            "method": method,
            "mean_m": float(np.mean(errors)),
            "min_m": min(errors),
            "max_m": max(errors),
            "to_beat": to_beat,
        }
        print(table.add(record), flush=True)
    reference = {"window_s": 0.0, "starts": "all fixes", "method": "u-blox fixes alone (no cut)", "mean_m": float(gnss_errors.mean())}
    print(table.add({**reference, "min_m": float(gnss_errors.min()), "max_m": float(gnss_errors.max()), "to_beat": "1.45 m mean"}), flush=True)
    plot_tracks("comma2k19_first_30s_window", truth.select(truth.timestamps <= first.timestamp + 30.0), plotted, out)


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--out", type=Path, default=Path("runs/ground_vehicles"))
    parser.add_argument("--only", nargs="+", default=["plaza1", "labyrinth", "comma2k19"], choices=["plaza1", "labyrinth", "comma2k19"])
    args = parser.parse_args()
    command = f"python bench/ground_vehicles.py --out {args.out} --only {' '.join(args.only)}"
    print(f"command: {command}\n")
    results = Results("ground_vehicles", command)
    caption = "Horizontal error against the truth at every odometry sample; same start pose for both methods"
    tracks = results.table("beacons", TRACK_COLUMNS, key=["dataset", "method"], caption=caption)
    print(caption)
    print(tracks.header())
    if "plaza1" in args.only:
        beacon_run(
            "plaza1", "cmu_plaza1_wheel_odometry", PLAZA_NOISE, lambda t: yaw_of(t.quats_xyzw[0]), ("4.45 m end, 1.93 m RMSE", "1.03 m RMSE"), tracks, args.out
        )
    if "labyrinth" in args.only:
        beacon_run(
            "labyrinth",
            "tuc_labyrinth_wheel_odometry",
            LABYRINTH_NOISE,
            first_motion_heading,
            ("0.38 m end, 0.21 m RMSE", "< odometry alone"),
            tracks,
            args.out,
        )
    if "comma2k19" in args.only:
        caption = "comma2k19: horizontal error at the end of each GNSS outage"
        print(f"\n{caption}")
        windows = results.table("comma2k19", WINDOW_COLUMNS, key=["window_s", "method"], caption=caption)
        print(windows.header())
        comma_run(windows, args.out)


if __name__ == "__main__":
    main()
