"""The SLAM engine on real sequences with ground truth (skipped when ../shared/data is absent).

Issue targets, with a 5 % margin; ORB-SLAM3 on this machine: MH01 0.0049-0.0050 m (359/360),
KITTI 06 0.056-0.089 m (50/51)."""

import itertools

import numpy as np
import pytest

from evp.config import OrbSettings, Settings, SlamSettings
from evp.io.map_files import load_map, save_map
from evp.io.registry import open_dataset
from evp.io.run_outputs import write_outputs
from evp.io.vocabulary_files import default_vocabulary_path, load_vocabulary
from evp.pipeline import run_dataset, run_frames
from evp.run_setup import camera_for, make_estimator, resolve_settings
from evp.runtime.slam import build_slam
from evp.slam.system import SlamSystem
from evp.types import TrackingState
from tests.conftest import shared
from tests.slam.relocalisation_trials import cover_lens_then_revisit, relocalisation_error

VOCABULARY = load_vocabulary(default_vocabulary_path())


@pytest.mark.parametrize(("sequence", "max_ate_m", "min_tracked"), [("euroc_mh_01_easy_moving_360", 0.0075, 0.98), ("kitti_odom_06_f000-050", 0.10, 0.95)])
def test_sequence_meets_the_accuracy_target(tmp_path, sequence, max_ate_m, min_tracked):
    dataset = open_dataset(shared(sequence))
    settings = resolve_settings(Settings(estimator="slam"), dataset)
    result = run_dataset(dataset, make_estimator(camera_for(dataset, settings), settings, dataset))
    metrics = write_outputs(result, dataset, settings, tmp_path)
    assert metrics["tracked_fraction"] >= min_tracked
    assert metrics["rmse"] <= max_ate_m * 1.05
    for name in ("trajectory.tum", "trajectory_live.tum", "keyframes.tum", "map.ply", "map.npz", "timing.json", "metrics.json", "settings.yaml"):
        assert (tmp_path / name).is_file()


@pytest.fixture(scope="module")
def euroc_start():
    dataset = open_dataset(shared("euroc_mh_01_easy_moving_360"))
    return dataset, list(itertools.islice(dataset.frames(), 150))


def test_relocalises_on_real_images(euroc_start):
    dataset, frames = euroc_start
    slam = SlamSystem(dataset.camera, OrbSettings(), SlamSettings(), vocabulary=VOCABULARY)
    first, again = cover_lens_then_revisit(slam, frames, 150, slice(100, 120))
    assert TrackingState.RELOCALIZED in [e.tracking_state for e in again]
    index, distance, angle = relocalisation_error(first, again, slice(100, 120))
    assert index < 5
    assert distance < 0.02 and angle < 1.0  # map units (median depth 1 = about 3.5 m here)


def test_mapping_worker_thread_on_real_images(euroc_start, tmp_path):
    """The live configuration: local mapping in its own thread, fed by the keyframe queue."""
    dataset, frames = euroc_start
    slam = build_slam(dataset.camera, OrbSettings(), SlamSettings(mapping="thread"), VOCABULARY)
    states = [slam.feed(frame).tracking_state for frame in frames]
    slam.finish()
    start = states.index(TrackingState.OK)  # 3 degrees of parallax: 1.5 s in
    assert start <= 40 and states[start:].count(TrackingState.OK) >= 0.95 * (len(frames) - start)
    stamps, _ = slam.refined_trajectory()
    refined = set(stamps.tolist())
    assert all(frame.timestamp in refined for frame in frames[start:])
    # the frames before the start too, swept back from the first keyframe against the final map;
    # with mapping in its thread that map, and so how far back the sweep reaches, varies with
    # timing: under load 0-10 of the 31 earliest frames went unlocalised over 20 runs
    assert sum(frame.timestamp in refined for frame in frames[:start]) >= start // 2
    assert len(slam.mapping_ms) >= 5 and slam.mapping.max_queue <= 2
    save_map(slam.map, tmp_path / "map.npz")
    loaded = load_map(tmp_path / "map.npz", slam.extractor.scale_factors)
    assert len(loaded.keyframes) == len(slam.map.keyframes) and len(loaded.points) == len(slam.map.points)


@pytest.mark.parametrize("seed", [1, 2])
def test_forward_driving_with_a_fifth_of_the_frames_dropped_stays_tracked(seed):
    """A busy station drops frames at random: the car's steps double now and then, most of the
    last frame's points change scale or leave the view, and tracking must hold (issue 29: 95 %)."""
    dataset = open_dataset(shared("kitti_odom_06_f000-050"))
    rng = np.random.default_rng(seed)
    frames = [frame for frame in dataset.frames() if rng.random() >= 0.2]
    settings = resolve_settings(Settings(estimator="slam"), dataset)
    result = run_frames(make_estimator(dataset.camera, settings, dataset), frames)
    assert len(result.final_trajectory()) >= 0.95 * len(frames)
