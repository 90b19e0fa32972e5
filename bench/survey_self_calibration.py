"""The photo survey's lens self-calibration: adjustments needed, time, lens found and positions
against GPS, for EVP's adjustment and a baseline implementation of ``adjust_survey`` (another
version of ``evp/vo/survey_adjustment.py``, e.g. main's), on the same inputs in one run.

The inputs (the nominal EXIF camera, the mosaic's poses, the matched tracks) come from running
the nadir odometry over the Toledo survey in ../shared/data once; they are cached in the system's
temporary folder, so a second run measures only the adjustments.

Usage: python bench/survey_self_calibration.py [--baseline PATH/survey_adjustment.py [--baseline-name NAME]]
"""

from __future__ import annotations

import argparse
import importlib.util
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from results import Results

from evp.config import EvalSettings, Settings
from evp.eval.evaluate import evaluate
from evp.io.registry import open_dataset
from evp.pipeline import run_dataset
from evp.run_setup import camera_for, make_estimator
from evp.types import Trajectory
from evp.vo import survey_adjustment
from evp.vo.survey_adjustment import SurveyTracks, tracks_from_matches

TOLEDO = Path(__file__).resolve().parents[2] / "shared" / "data" / "aerial_nadir_odm_toledo_fc350"
ADJUSTMENTS = ("_adjust", "_self_calibrate")  # the functions that run one bundle adjustment
CACHE = Path(tempfile.gettempdir()) / "evp-bench-toledo-survey-inputs.npz"
COLUMNS = [
    ("implementation", "{method}"),
    ("adjustments", "{adjustments}"),
    ("time (s; compare within one run)", "{seconds:.0f}"),
    ("f (px; EXIF 693)", "{f_px:.1f}"),
    ("k1", "{k1:.3f}"),
    ("k2", "{k2:.3f}"),
    ("ATE vs GPS, Sim3 (m)", "{ate_m:.2f}"),
]


def survey_inputs():
    """(camera, mosaic poses, tracks, photo times) of the Toledo survey, cached after the first run."""
    dataset = open_dataset(TOLEDO)
    if CACHE.is_file():
        data = np.load(CACHE)
        camera = camera_for(dataset, Settings())
        return camera, data["poses"], SurveyTracks(data["image_index"], data["track_index"], data["pixels"]), data["stamps"], dataset
    settings = Settings(estimator="nadir")
    camera = camera_for(dataset, settings)
    estimator = make_estimator(camera, settings, dataset)
    run_dataset(dataset, estimator, lambda n: None)
    placed = estimator._placed
    poses = np.array([p.T_world_cam for p in placed])
    stamps = np.array([p.timestamp for p in placed])
    tracks = tracks_from_matches([p.pixels for p in placed], estimator._matches)
    np.savez(CACHE, poses=poses, stamps=stamps, image_index=tracks.image_index, track_index=tracks.track_index, pixels=tracks.pixels)
    return camera, poses, tracks, stamps, dataset


def load_module(path: Path):
    spec = importlib.util.spec_from_file_location("baseline_survey_adjustment", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def measure(module, name: str, camera, poses, tracks, stamps, dataset) -> dict:
    """One self-calibrated adjustment with ``module``'s adjust_survey, its bundle adjustments
    counted (the module's ``_adjust``, one per lens tried, and ``_self_calibrate``, the
    adjustment with the lens among its variables, where it has one)."""
    calls = [0]
    originals = {attribute: getattr(module, attribute) for attribute in ADJUSTMENTS if hasattr(module, attribute)}

    def counted(adjust):
        def call(*args):
            calls[0] += 1
            return adjust(*args)

        return call

    for attribute, adjust in originals.items():
        setattr(module, attribute, counted(adjust))
    try:
        start = time.perf_counter()
        adjusted, lens = module.adjust_survey(camera, poses, tracks)
        seconds = time.perf_counter() - start
    finally:
        for attribute, adjust in originals.items():
            setattr(module, attribute, adjust)
    estimate = Trajectory.from_poses(adjusted, stamps, "adjusted")
    summary = evaluate(dataset.ground_truth, estimate, EvalSettings(align="sim3", max_time_diff_s=0.5, rotation=False)).summary()
    return {"method": name, "adjustments": calls[0], "seconds": seconds, "f_px": lens.fx, "k1": lens.k1, "k2": lens.k2, "ate_m": summary["rmse"]}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--baseline", type=Path, help="another survey_adjustment.py to compare with (e.g. main's)")
    parser.add_argument("--baseline-name", default="baseline: Gauss-Newton lens search (main)", help="its row's name")
    args = parser.parse_args()
    if not TOLEDO.is_dir():
        sys.exit(f"needs {TOLEDO}")
    camera, poses, tracks, stamps, dataset = survey_inputs()
    print(f"Toledo: {len(poses)} photos, {tracks.num_tracks} tracks, {len(tracks.image_index)} observations", flush=True)
    results = Results("survey_self_calibration", " ".join(["python", *sys.argv]))
    caption = "The Toledo survey's lens self-calibration on the same cached inputs: adjustments needed, lens found, positions against GPS. The lenses lie on the focal-height ridge the module doc describes."
    table = results.table("toledo", COLUMNS, key=["method"], caption=caption)
    print(table.header())
    ours = measure(survey_adjustment, "EVP: one adjustment, lens among the variables", camera, poses, tracks, stamps, dataset)
    print(table.add(ours), flush=True)
    if args.baseline is not None:
        baseline = measure(load_module(args.baseline), args.baseline_name, camera, poses, tracks, stamps, dataset)
        print(table.add(baseline), flush=True)


if __name__ == "__main__":
    main()
