"""Write a simulated dataset to disk in EVP's EuRoC-like layout (docs/simulator.md).

``mav0/cam0`` images + ``sensor.yaml`` (intrinsics, distortion, T_BS), ``mav0/imu0``,
``mav0/state_groundtruth_estimate0`` (body pose, velocity, IMU biases), and the sensors EuRoC
lacks in the same CSV style: ``gps0``, ``baro0``, ``range0``, ``wheel0``, ``wifi0`` (with the survey
of its access points as ``wifi_radio_map.npz`` beside ``mav0``). ``sim.yaml``
records the scenario, every option, the geodetic origin and the events (spoofing, outages, drops).
"""

from __future__ import annotations

import multiprocessing
import os
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import yaml

from evp.io.trajectory import write_trajectory
from evp.io.wifi_uji import save_radio_map
from evp.sim import sensors
from evp.sim.camera_effects import render_frame
from evp.sim.scenarios import Scenario, SimOptions, build_scenario
from evp.sim.world import Renderer, ray_distance
from evp.types import LensModel, Trajectory

EPOCH_S = 1_700_000_000  # simulated clocks start here (2023-11-14), like real sensor clocks
IMAGE_PARAMS = {"png": [cv2.IMWRITE_PNG_COMPRESSION, 1], "jpg": [cv2.IMWRITE_JPEG_QUALITY, 95]}


@dataclass
class SimResult:
    path: Path
    scenario: Scenario
    frames: int
    dropped: list[int]


def _ns(t: np.ndarray | float) -> np.ndarray:
    return np.round((np.asarray(t, dtype=np.float64) + EPOCH_S) * 1e9).astype(np.int64)


# --- images, rendered by worker processes that rebuild the (seeded, deterministic) scenario ------------

_WORKER: dict = {}


def _init_worker(name: str, options: SimOptions, single_threaded: bool) -> None:
    if single_threaded:
        cv2.setNumThreads(1)  # one process per core already: OpenCV's own threads would only contend
    scenario = build_scenario(name, options)
    _WORKER.update(scenario=scenario, options=options, renderer=Renderer(scenario.camera, scenario.scene))


def _render_chunk(task: tuple[list[int], list[float], str]) -> int:
    indices, times, folder = task
    scenario, options, renderer = _WORKER["scenario"], _WORKER["options"], _WORKER["renderer"]
    for index, t in zip(indices, times):
        image = render_frame(renderer, scenario, t, options, frame_seed=options.seed * 1_000_003 + index)
        cv2.imwrite(os.path.join(folder, f"{_ns(t)}.{options.image_format}"), image, IMAGE_PARAMS[options.image_format])
    return len(indices)


def _render_images(
    name: str,
    scenario: Scenario,
    options: SimOptions,
    indices: list[int],
    times: np.ndarray,
    folder: Path,
    workers: int,
    progress: Callable[[int], None] | None,
) -> None:
    chunk = 25
    tasks = [(indices[i : i + chunk], list(times[i : i + chunk]), str(folder)) for i in range(0, len(indices), chunk)]
    if workers <= 1:
        _WORKER.update(scenario=scenario, options=options, renderer=Renderer(scenario.camera, scenario.scene))
        for task in tasks:
            done = _render_chunk(task)
            if progress:
                progress(done)
        _WORKER.clear()
        return
    # spawned (not forked) workers: forking a process whose OpenCV thread pool is running can deadlock
    with multiprocessing.get_context("spawn").Pool(workers, initializer=_init_worker, initargs=(name, options, True)) as pool:
        for done in pool.imap(_render_chunk, tasks):
            if progress:
                progress(done)


# --- writers -------------------------------------------------------------------------------------------


def _write_csv(path: Path, header: str, rows: list[list]) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("w") as handle:
        handle.write(header + "\n")
        for row in rows:
            handle.write(",".join(repr(v) if isinstance(v, float) else str(v) for v in row) + "\n")


def _camera_yaml(scenario: Scenario, options: SimOptions) -> str:
    """EuRoC's camera sensor.yaml, in Kalibr's model names: pinhole with radial-tangential (its four
    coefficients, all of OpenCV's when k3 or the rational terms are used) or equidistant."""
    c = scenario.camera
    coefficients = [float(v) for v in c.distortion]
    if c.lens is LensModel.RADTAN and not any(coefficients[4:]):
        coefficients = coefficients[:4]
    return yaml.safe_dump(
        {
            "sensor_type": "camera",
            "comment": f"EVP simulator, {c.name}",
            "T_BS": {"cols": 4, "rows": 4, "data": [float(v) for v in scenario.T_body_cam.ravel()]},
            "rate_hz": options.fps,
            "resolution": [c.width, c.height],
            "camera_model": "pinhole",
            "intrinsics": [c.fx, c.fy, c.cx, c.cy],
            "distortion_model": "radial-tangential" if c.lens is LensModel.RADTAN else "equidistant",
            "distortion_coefficients": coefficients,
            "rolling_shutter_readout_s": options.rolling_shutter_s,
            "exposure_s": options.exposure_s,
        },
        sort_keys=False,
    )


def generate(
    name: str, options: SimOptions, out: Path, workers: int = 2, progress: Callable[[int], None] | None = None, on_start: Callable[[int], None] | None = None
) -> SimResult:
    """Build the scenario, render its frames and sample every sensor into ``out``."""
    scenario = build_scenario(name, options)
    rng = np.random.default_rng(options.seed)
    start, end = scenario.motion.start, scenario.motion.end
    all_times = np.arange(start, end + 1e-9, 1.0 / options.fps)
    kept = rng.uniform(size=len(all_times)) >= options.drop_probability
    kept[0] = True
    indices = list(np.flatnonzero(kept))
    times = all_times[kept]
    mav0 = out / "mav0"
    image_dir = mav0 / "cam0" / "data"
    image_dir.mkdir(parents=True, exist_ok=True)
    if on_start:
        on_start(len(indices))
    _render_images(name, scenario, options, indices, times, image_dir, workers, progress)
    _write_csv(mav0 / "cam0" / "data.csv", "#timestamp [ns],filename", [[int(n), f"{n}.{options.image_format}"] for n in _ns(times)])
    (mav0 / "cam0" / "sensor.yaml").write_text(_camera_yaml(scenario, options))

    # ground truth of the body at the IMU rate, and of the camera at every written frame
    imu_times = sensors.sample_times(start, end, options.imu.rate_hz)
    imu_state = scenario.motion.state(imu_times)
    imu = sensors.simulate_imu(imu_state, options.imu, np.random.default_rng([options.seed, 1]))
    q = imu_state.rotation.as_quat()
    gt_rows = [
        [int(n), *map(float, p), float(qq[3]), float(qq[0]), float(qq[1]), float(qq[2]), *map(float, v), *map(float, bw), *map(float, ba)]
        for n, p, qq, v, bw, ba in zip(_ns(imu_times), imu_state.position, q, imu_state.velocity, imu.gyro_bias, imu.accel_bias)
    ]
    _write_csv(
        mav0 / "state_groundtruth_estimate0" / "data.csv",
        "#timestamp [ns],p_RS_R_x [m],p_RS_R_y [m],p_RS_R_z [m],q_RS_w [],q_RS_x [],q_RS_y [],q_RS_z [],v_RS_R_x [m s^-1],v_RS_R_y [m s^-1],v_RS_R_z [m s^-1],"
        "b_w_RS_S_x [rad s^-1],b_w_RS_S_y [rad s^-1],b_w_RS_S_z [rad s^-1],b_a_RS_S_x [m s^-2],b_a_RS_S_y [m s^-2],b_a_RS_S_z [m s^-2]",
        gt_rows,
    )
    write_trajectory(out / "groundtruth_cam0_tum.txt", Trajectory.from_poses(scenario.camera_poses(times), times + EPOCH_S))
    if "imu" in scenario.sensors:
        _write_csv(
            mav0 / "imu0" / "data.csv",
            "#timestamp [ns],w_RS_S_x [rad s^-1],w_RS_S_y [rad s^-1],w_RS_S_z [rad s^-1],a_RS_S_x [m s^-2],a_RS_S_y [m s^-2],a_RS_S_z [m s^-2]",
            [[int(n), *s.angular_velocity_rad_s, *s.linear_acceleration_m_s2] for n, s in zip(_ns(imu_times), imu.samples)],
        )
        (mav0 / "imu0" / "sensor.yaml").write_text(
            yaml.safe_dump(
                {"sensor_type": "imu", "T_BS": {"cols": 4, "rows": 4, "data": np.eye(4).ravel().tolist()}, **options.imu.model_dump()}, sort_keys=False
            )
        )
    _write_other_sensors(scenario, options, mav0)
    (out / "sim.yaml").write_text(yaml.safe_dump(_description(scenario, options, len(all_times), [int(i) for i in np.flatnonzero(~kept)]), sort_keys=False))
    return SimResult(out, scenario, len(indices), [int(i) for i in np.flatnonzero(~kept)])


def _write_other_sensors(scenario: Scenario, options: SimOptions, mav0: Path) -> None:
    start, end = scenario.motion.start, scenario.motion.end

    def state(rate):
        return scenario.motion.state(sensors.sample_times(start, end, rate))

    if "gps" in scenario.sensors:
        fixes = sensors.simulate_gps(state(options.gps.rate_hz), options.gps, scenario.origin, np.random.default_rng([options.seed, 2]))
        _write_csv(
            mav0 / "gps0" / "data.csv",
            "#timestamp [ns],latitude [deg],longitude [deg],altitude [m],horizontal_accuracy [m],vertical_accuracy [m]",
            [[int(_ns(f.timestamp)), f.latitude_deg, f.longitude_deg, f.altitude_m, f.horizontal_accuracy_m, f.vertical_accuracy_m] for f in fixes],
        )
    if "baro" in scenario.sensors:
        samples = sensors.simulate_baro(state(options.baro.rate_hz), options.baro, scenario.origin[2], np.random.default_rng([options.seed, 3]))
        _write_csv(
            mav0 / "baro0" / "data.csv", "#timestamp [ns],pressure [Pa],altitude [m]", [[int(_ns(s.timestamp)), s.pressure_pa, s.altitude_m] for s in samples]
        )
    if "wheel" in scenario.sensors:
        samples = sensors.simulate_wheels(state(options.wheel.rate_hz), options.wheel, np.random.default_rng([options.seed, 4]))
        _write_csv(
            mav0 / "wheel0" / "data.csv",
            "#timestamp [ns],left [m s^-1],right [m s^-1],forward [m s^-1],yaw_rate [rad s^-1]",
            [[int(_ns(s.timestamp)), *s.wheel_speeds_m_s, s.forward_speed_m_s, s.yaw_rate_rad_s] for s in samples],
        )
    if "range" in scenario.sensors:
        samples = sensors.simulate_range(
            state(options.range.rate_hz), options.range, lambda p, d: ray_distance(scenario.scene, p, d), np.random.default_rng([options.seed, 5])
        )
        _write_csv(mav0 / "range0" / "data.csv", "#timestamp [ns],distance [m]", [[int(_ns(s.timestamp)), s.distance_m] for s in samples])
    if "wifi" in scenario.sensors:
        scans = sensors.simulate_wifi(state(options.wifi.rate_hz), options.wifi, scenario.access_points, np.random.default_rng([options.seed, 6]))
        _write_csv(
            mav0 / "wifi0" / "data.csv",
            "#timestamp [ns],bssid,rssi [dBm]",
            [[int(_ns(s.timestamp)), bssid, rssi] for s in scans for bssid, rssi in s.rssi_dbm.items()],
        )
        write_wifi_survey(scenario, options, mav0.parent)


def write_wifi_survey(scenario: Scenario, options: SimOptions, out: Path) -> Path:
    """``out/wifi_radio_map.npz``: the survey of the room's access points (``evp wifi build``'s
    format), the radio map ``wifi.radio_map`` can name to fuse the rendered scans."""
    path = scenario.motion.state(sensors.sample_times(scenario.motion.start, scenario.motion.end, 10.0)).position
    survey = sensors.simulate_wifi_survey(path, options.wifi, scenario.access_points, np.random.default_rng([options.seed, 7]))
    save_radio_map(survey, out / "wifi_radio_map.npz")
    return out / "wifi_radio_map.npz"


def _description(scenario: Scenario, options: SimOptions, rendered: int, dropped: list[int]) -> dict:
    return {
        "generator": "evp sim",
        "scenario": scenario.name,
        "notes": scenario.notes,
        "clock_epoch_s": EPOCH_S,
        "duration_s": scenario.motion.duration,
        "frames": rendered - len(dropped),
        "dropped_frames": dropped,
        "geodetic_origin": {"latitude_deg": scenario.origin[0], "longitude_deg": scenario.origin[1], "altitude_m": scenario.origin[2]},
        "world_frame": "ENU at the geodetic origin; body frame x forward, y left, z up",
        "sensors": list(scenario.sensors),
        "camera_mount": "gimbal (level)" if scenario.gimbal else "fixed to the body",
        "access_points_enu_m": scenario.access_points.tolist(),
        "options": options.model_dump(mode="json"),
    }
