"""The main job end to end on the bundled sample, and how runs survive bad frames."""

import json
import shutil
import subprocess
import sys

import cv2
import numpy as np
import pytest

from evp.config import Settings
from evp.errors import DatasetError, FrameError
from evp.estimator import Estimator
from evp.io.registry import open_dataset
from evp.io.run_outputs import write_outputs
from evp.pipeline import Pipeline, RealTime, RunResult, Sink, Stage, run_dataset, run_frames
from evp.run_setup import make_estimator, resolve_settings
from evp.types import Frame, ImuSample, PoseEstimate, TrackingState
from tests.conftest import SAMPLE
from tests.io import builders


def test_sample_run_tracks_and_is_accurate(tmp_path):
    dataset = open_dataset(SAMPLE)
    result = run_dataset(dataset, make_estimator(dataset.camera, Settings()))
    metrics = write_outputs(result, dataset, resolve_settings(Settings(), dataset), tmp_path)
    # the SLAM issue's target for this sequence, with its 5 % margin (measured 0.0086 m, 87/87)
    assert metrics["tracked_fraction"] >= 0.9
    assert metrics["rmse"] <= 0.01 * 1.05
    assert metrics["init_frame"] <= 10
    assert metrics["loop_closures"] == []  # a slider's back-and-forth stays covisible: nothing to close
    assert metrics["gyro_aided_tracking"] is False  # the sample has no IMU
    # trajectory.tum is the globally adjusted map's, trajectory_live.tum the poses as answered
    assert (tmp_path / "trajectory_live.tum").read_text() != (tmp_path / "trajectory.tum").read_text()
    assert result.estimates[0].tracking_state is TrackingState.NOT_INITIALIZED
    for name in ("trajectory.tum", "states.csv", "timing.json", "metrics.json", "settings.yaml", "plots/top_view.png"):
        assert (tmp_path / name).is_file()
    assert len(json.loads((tmp_path / "timing.json").read_text())["tracking_ms"]) == 87
    dataset.ground_truth = None  # a video without ground truth: its track is still drawn, in map units
    write_outputs(result, dataset, resolve_settings(Settings(), dataset), tmp_path / "no_truth")
    assert sorted(p.name for p in (tmp_path / "no_truth" / "plots").iterdir()) == ["trajectory.png"]


def test_run_is_deterministic():
    dataset = open_dataset(SAMPLE)
    first = run_dataset(dataset, make_estimator(dataset.camera, Settings())).trajectory()
    second = run_dataset(dataset, make_estimator(dataset.camera, Settings())).trajectory()
    assert np.array_equal(first.positions, second.positions)


def test_bad_frames_are_skipped_and_reported(tmp_path):
    root = builders.make_image_folder(tmp_path / "ds", count=30)
    images = sorted((root / "images").glob("*.png"))
    images[5].write_bytes(b"not a png")  # corrupt
    cv2.imwrite(str(images[9]), np.zeros((90, 120), np.uint8))  # wrong size
    lines = (root / "images.txt").read_text().splitlines()
    lines[12] = lines[11].split()[0] + " " + lines[12].split()[1]  # duplicate timestamp
    (root / "images.txt").write_text("\n".join(lines) + "\n")
    with pytest.raises(DatasetError, match="must increase"):
        open_dataset(root)  # the reader refuses non-increasing stamps outright...
    lines[12] = f"{float(lines[11].split()[0]) + 0.001:.6f} " + lines[12].split()[1]
    (root / "images.txt").write_text("\n".join(lines) + "\n")
    dataset = open_dataset(root)
    result = run_dataset(dataset, make_estimator(dataset.camera, Settings()))
    assert len(result.estimates) == 28
    assert any("cannot be decoded" in s for s in result.skipped)
    assert any("120x90" in s for s in result.skipped)


def test_run_without_calibration_is_a_clear_error(tmp_path):
    root = tmp_path / "vid"
    video = builders.make_video(root)
    proc = subprocess.run([sys.executable, "-m", "evp.cli", "run", str(video), "--out", str(tmp_path / "o")], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 3 and "no calibration" in proc.stderr  # bad input data
    shutil.rmtree(root)


class _Slider(Estimator):
    """A real, exact estimator for the pipeline's contract: the camera slides 1 m along x per
    second; an all-black image is refused as a frame it cannot use."""

    def __init__(self):
        self.calls: list[str] = []

    def feed(self, frame: Frame) -> PoseEstimate:
        self.calls.append(f"feed {frame.index}")
        if not frame.image.any():
            raise FrameError(f"frame {frame.index}: blank")
        pose = np.eye(4)
        pose[0, 3] = frame.timestamp
        return PoseEstimate(frame.timestamp, pose, TrackingState.OK, 100)

    def settle(self) -> None:
        self.calls.append("settle")

    def finish(self) -> None:
        self.calls.append("finish")


class _Log(Sink):
    def __init__(self, calls: list[str]):
        self.calls = calls

    def on_estimate(self, frame, estimate, elapsed_ms):
        self.calls.append(f"sink {frame.index} x={estimate.T_world_cam[0, 3]:g}")

    def on_skip(self, frame, reason):
        self.calls.append(f"skip {reason}")

    def on_drop(self, frame):
        self.calls.append(f"drop {frame.index}")

    def on_finish(self, estimator):
        self.calls.append("sink finish")


class _Lift:
    """A stage: raises every estimate by 1 m (as a navigation filter would change it)."""

    def process(self, frame, estimate):
        pose = estimate.T_world_cam.copy()
        pose[2, 3] += 1.0
        return PoseEstimate(estimate.timestamp, pose, estimate.tracking_state, estimate.quality)


def _frames(stamps, blank=()):
    return [Frame(t, np.zeros((4, 4), np.uint8) if k in blank else np.full((4, 4), 9, np.uint8), k) for k, t in enumerate(stamps)]


def test_pipeline_order_is_feed_stages_sinks_settle_then_finish():
    estimator = _Slider()
    result = RunResult(estimator)
    Pipeline(estimator, [_Log(estimator.calls), result], [_Lift()]).run(_frames([0.0, 0.5]))
    assert estimator.calls == ["feed 0", "sink 0 x=0", "settle", "feed 1", "sink 1 x=0.5", "settle", "finish", "sink finish"]
    assert [e.T_world_cam[2, 3] for e in result.estimates] == [1.0, 1.0]  # sinks see the stages' output
    assert len(result.tracking_ms) == 2
    assert len(result.feed_cpu_ms) == 2 and min(result.feed_cpu_ms) >= 0.0  # the feed's thread CPU time, per frame


class _Watch(Stage):
    """A stage that logs the telemetry it observes (``observe`` overridden) and passes estimates on."""

    def __init__(self, calls: list[str]):
        self.calls = calls

    def observe(self, record):
        self.calls.append(f"imu {record.timestamp:g}")

    def process(self, frame, estimate):
        return estimate


def test_telemetry_reaches_the_stages_before_the_frames_not_older_than_it():
    estimator = _Slider()
    imu = [ImuSample(t, (0.0, 0.0, 0.0), (0.0, 0.0, 9.8)) for t in (0.0, 0.25, 0.5, 0.75, 1.5)]
    Pipeline(estimator, [_Log(estimator.calls)], [_Watch(estimator.calls)]).run(_frames([0.0, 0.5, 1.0]), imu)
    assert estimator.calls == [
        *["imu 0", "feed 0", "sink 0 x=0", "settle"],
        *["imu 0.25", "imu 0.5", "feed 1", "sink 1 x=0.5", "settle"],
        *["imu 0.75", "feed 2", "sink 2 x=1", "settle"],
        *["finish", "sink finish"],  # the record after the last frame answers no frame
    ]
    assert Stage.observe(_Lift(), imu[0]) is None  # the protocol's default: a stage that needs no telemetry


def test_pipeline_skips_refused_frames_and_time_going_backwards():
    estimator = _Slider()
    result = RunResult(estimator)
    Pipeline(estimator, [result]).run(_frames([0.0, 0.1, 0.1, 0.05, 0.3], blank={1}))
    # a refused frame does not advance time: the next one with the same stamp is still used
    assert [e.timestamp for e in result.estimates] == [0.0, 0.1, 0.3]
    assert result.skipped == ["frame 1: blank", "frame 3: timestamp 0.05 does not increase"]


def test_real_time_pacing_reports_drops_to_the_sinks():
    class Clock:
        now = 0.0

        def __call__(self):
            return self.now

        def sleep(self, seconds):
            self.now += seconds

    clock = Clock()

    class Slow(_Slider):
        def feed(self, frame):
            clock.now += 0.25  # each frame takes 250 ms: two of every three at 10 Hz are overtaken
            return super().feed(frame)

    estimator = Slow()
    result = RunResult(estimator)
    Pipeline(estimator, [result], pacing=RealTime(1.0, clock, clock.sleep)).run(_frames([0.1 * k for k in range(10)]))
    assert len(result.estimates) + len(result.dropped) == 10
    assert result.dropped and set(result.dropped).isdisjoint(int(round(e.timestamp * 10)) for e in result.estimates)


def test_run_result_uses_the_estimators_refined_trajectory():
    class Refined(_Slider):
        def refined_trajectory(self):
            return np.array([0.0]), np.eye(4)[None]

    estimator = Refined()
    result = RunResult(estimator)
    Pipeline(estimator, [result]).run(_frames([0.0, 1.0]))
    assert len(result.trajectory()) == 2 and len(result.final_trajectory()) == 1


def test_a_run_that_fails_closes_the_estimator():
    class Faulty(_Slider):
        def feed(self, frame):
            if frame.index == 1:
                raise RuntimeError("a bug")
            return super().feed(frame)

        def close(self):
            self.calls.append("close")

    estimator = Faulty()
    with pytest.raises(RuntimeError, match="a bug"):
        Pipeline(estimator).run(_frames([0.0, 0.1, 0.2]))
    assert estimator.calls == ["feed 0", "settle", "close"]  # closed, not finished


def test_the_refined_trajectory_is_asked_of_the_estimator_once():
    asked = []

    class Refined(_Slider):
        def refined_trajectory(self):
            asked.append(1)
            return np.array([0.0]), np.eye(4)[None]

    estimator = Refined()
    result = run_frames(estimator, _frames([0.0, 1.0]))
    assert result.final_trajectory() is result.final_trajectory() is result.refined
    assert len(asked) == 1


def test_an_estimator_must_say_how_it_feeds():
    class Incomplete(Estimator):
        pass

    with pytest.raises(TypeError, match="feed"):
        Incomplete()
