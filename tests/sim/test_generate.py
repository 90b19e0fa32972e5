"""Every scenario generates with one command and reads back through the dataset readers."""

import json
import subprocess
import sys

import numpy as np
import pytest
import yaml

from evp.io.registry import open_dataset
from evp.sim.generate import EPOCH_S, generate
from evp.sim.scenarios import SCENARIOS, SimOptions
from evp.types import LensModel

REQUIRED = {"drone-flight", "circle-indoor", "wheel-robot-room", "marker-field"}


def evp(*args):
    return subprocess.run([sys.executable, "-m", "evp.cli", *map(str, args)], capture_output=True, text=True, timeout=600)


def test_list_prints_one_scenario_per_line():
    result = evp("sim", "--list")
    assert result.returncode == 0
    names = result.stdout.split()
    assert REQUIRED <= set(names) and names == list(SCENARIOS)


@pytest.mark.parametrize("scenario", sorted(SCENARIOS))
def test_scenario_generates_and_loads(tmp_path, scenario):
    result = generate(scenario, SimOptions(duration_s=1.0, seed=3, fps=10.0), tmp_path / scenario, workers=1)
    dataset = open_dataset(tmp_path / scenario)
    assert dataset.format == "euroc"
    assert dataset.num_frames == result.frames == 11
    camera = result.scenario.camera
    assert (dataset.camera.fx, dataset.camera.cy, dataset.camera.k1, dataset.camera.width) == (camera.fx, camera.cy, camera.k1, camera.width)
    frame = next(dataset.frames())
    assert frame.image.shape == (dataset.camera.height, dataset.camera.width)
    assert frame.image.std() > 5  # a textured view, not an empty render
    assert dataset.ground_truth is not None and len(dataset.imu) == 201
    expected = {"gps": "gps", "baro": "baro", "wheel": "wheel", "range": "ranges", "wifi": "wifi"}
    for sensor, attribute in expected.items():
        assert bool(getattr(dataset, attribute)) == (sensor in result.scenario.sensors), sensor
    described = yaml.safe_load((tmp_path / scenario / "sim.yaml").read_text())
    assert described["scenario"] == scenario and described["options"]["seed"] == 3


def test_camera_ground_truth_matches_body_ground_truth_times_extrinsics(tmp_path):
    from evp.config import EvalSettings
    from evp.eval.evaluate import evaluate
    from evp.io.trajectory import read_trajectory

    generate("wheel-robot-room", SimOptions(duration_s=2.0, fps=10.0), tmp_path, workers=1)
    dataset = open_dataset(tmp_path)
    camera_truth = read_trajectory(tmp_path / "groundtruth_cam0_tum.txt")
    assert camera_truth.timestamps[0] == pytest.approx(EPOCH_S)
    summary = evaluate(dataset.ground_truth, camera_truth, EvalSettings(align="none", max_time_diff_s=1e-6)).summary()
    assert summary["matched_poses"] == len(camera_truth)
    assert summary["max"] < 1e-9 and summary["ape_rotation_deg"]["max"] < 1e-6


def test_command_line_generation_with_events_then_info_and_run(tmp_path):
    out = tmp_path / "flight"
    result = evp(
        "sim",
        "drone-flight",
        "--out",
        out,
        "--duration",
        8,
        "--seed",
        2,
        "--flat",
        "--altitude",
        30,
        "--fps",
        15,
        "--drop",
        0.2,
        "--spoof-start",
        4,
        "--spoof-mode",
        "jump",
        "--gps-outage",
        "1:2",
        "--gps-clock-offset",
        0.3,
        "--workers",
        2,
    )
    assert result.returncode == 0, result.stderr
    described = yaml.safe_load((out / "sim.yaml").read_text())
    assert described["dropped_frames"] and described["frames"] == 121 - len(described["dropped_frames"])
    assert described["options"]["gps"]["spoof_start_s"] == 4 and described["options"]["gps"]["outages"] == [[1.0, 2.0]]
    info = evp("info", out, "--json")
    assert info.returncode == 0, info.stderr
    summary = json.loads(info.stdout)
    assert summary["frames"] == described["frames"]
    assert summary["sensors"]["gps"]["samples"] == 81 - 20  # 10 Hz for 8 s, 2 s jammed
    run = evp("run", out, "--out", tmp_path / "run")
    assert run.returncode == 0, run.stderr
    assert (tmp_path / "run" / "trajectory.tum").is_file()


def test_same_seed_same_dataset(tmp_path):
    for name in ("a", "b"):
        generate("marker-field", SimOptions(duration_s=0.5, seed=9, fps=10.0), tmp_path / name, workers=1)
    first = sorted((tmp_path / "a" / "mav0" / "cam0" / "data").iterdir())
    second = sorted((tmp_path / "b" / "mav0" / "cam0" / "data").iterdir())
    assert [p.read_bytes() for p in first] == [p.read_bytes() for p in second]
    assert (tmp_path / "a" / "mav0" / "imu0" / "data.csv").read_text() == (tmp_path / "b" / "mav0" / "imu0" / "data.csv").read_text()


def test_bad_options_are_clear_errors(tmp_path):
    unknown = evp("sim", "moon-landing", "--out", tmp_path / "x")
    assert unknown.returncode == 2 and "unknown scenario" in unknown.stderr
    bad = evp("sim", "drone-flight", "--out", tmp_path / "y", "--gps-outage", "soon")
    assert bad.returncode == 2 and "START:DURATION" in bad.stderr
    config = tmp_path / "sim.yaml"
    config.write_text("imu:\n  rate_hz: -5\n")
    invalid = evp("sim", "circle-indoor", "--out", tmp_path / "z", "--config", config)
    assert invalid.returncode == 2 and "imu.rate_hz" in invalid.stderr
    assert not (tmp_path / "z").exists()


def test_texture_from_image_files(tmp_path):
    import cv2

    photo = tmp_path / "photo.jpg"
    cv2.imwrite(str(photo), np.random.default_rng(0).integers(0, 255, (300, 400), dtype=np.uint8))
    result = generate("hover-drift", SimOptions(duration_s=0.5, fps=4.0, texture=f"{photo},{photo}"), tmp_path / "out", workers=1)
    assert result.frames == 3


def test_fisheye_dataset_reads_back_as_the_same_fisheye(tmp_path):
    options = SimOptions(duration_s=0.2, fps=10.0, camera="global_shutter_752x480", lens="fisheye", fisheye_fov_deg=170.0)
    result = generate("hover-drift", options, tmp_path, workers=1)
    sensor = yaml.safe_load((tmp_path / "mav0" / "cam0" / "sensor.yaml").read_text())
    assert (sensor["camera_model"], sensor["distortion_model"]) == ("pinhole", "equidistant")
    camera = open_dataset(tmp_path).camera
    assert camera.lens is LensModel.EQUIDISTANT and camera.width == 752
    assert camera.K.tolist() == result.scenario.camera.K.tolist() and camera.distortion.tolist() == result.scenario.camera.distortion.tolist()
    corner = camera.bearings(np.array([[-0.5, -0.5]]))[0]
    assert np.degrees(np.arccos(corner[2])) == pytest.approx(85.0)
