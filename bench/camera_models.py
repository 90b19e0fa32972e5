"""`evp run` on rendered flights seen through the pinhole preset and through a fisheye at the same
resolution: does the SLAM engine hold its accuracy on a wide lens? Issue 29's target is the
fisheye figures (ATE as a share of the path, frames tracked) within 20 % of the pinhole ones;
the ATE is compared on the frame times both lenses track, each against its own render's truth.

Usage: python bench/camera_models.py [--out runs/camera_models] [--fov 150] [--seeds 1 2 3] [--drone-seeds 1]

Renders each scenario twice with `evp sim` (same scene, noise and motion, except that a survey's
lines are spaced by the lens's footprint; `--lens pinhole` with the
nexus5x_640x380 preset, then `--lens fisheye --fisheye-fov FOV`, equidistant, diagonal field), runs
each through the same code as `evp run` (SLAM, mapping inline, deterministic) and prints one row
per run, then one row per scenario comparing the means. Scenarios: the circle (26 s, one lap, as
in run_sequences.py) for each of `--seeds`, and a short drone flight (60 s at 30 m, 15 fps:
take-off, a lawn-mower leg, landing) for each of `--drone-seeds`. Needs no shared data; the
renders take most of the time (about 40 minutes on two cores for the defaults).
"""

from __future__ import annotations

import argparse
import platform
import tempfile
from pathlib import Path

import numpy as np
from results import Results
from run_sequences import _record

from evp.config import Settings
from evp.eval.association import associate
from evp.eval.metrics import Alignment, align_trajectory, ape_translation
from evp.io.registry import open_dataset
from evp.io.trajectory import read_trajectory
from evp.sim.generate import generate
from evp.sim.scenarios import SimOptions

SCENARIOS = {
    "circle-indoor": dict(duration_s=26.0, fps=30.0),  # one lap, as bench/run_sequences.py renders it
    "drone-flight": dict(duration_s=60.0, fps=15.0, altitude_m=30.0),
}
TARGET = 0.2  # issue 29: fisheye within 20 % of the pinhole figures

RUN_COLUMNS = [
    ("scenario", "{scenario}"),
    ("seed", "{seed}"),
    ("lens", "{lens}"),
    ("ATE Sim3 (m)", "{ate_m:.4f}"),
    ("ATE / path", "{ate_path_percent:.2f} %"),
    ("tracked", "{tracked_percent:.1f} % ({tracked_frames}/{frames})"),
    ("frames to initialise", "{init_frame}"),
    ("ms/frame median", "{tracking_ms_median:.1f}"),
]
COMPARISON_COLUMNS = [
    ("scenario", "{scenario}"),
    ("seeds", "{seeds}"),
    ("ATE / path pinhole", "{pinhole_ate_path_percent:.2f} %"),
    ("ATE / path fisheye", "{fisheye_ate_path_percent:.2f} %"),
    ("tracked pinhole", "{pinhole_tracked_percent:.1f} %"),
    ("tracked fisheye", "{fisheye_tracked_percent:.1f} %"),
    ("ATE / path on frames both track: pinhole", "{pinhole_common_ate_path_percent:.2f} %"),
    ("fisheye", "{fisheye_common_ate_path_percent:.2f} %"),
    ("fisheye within 20 %", "{within_target}"),
]


def _lens_options(lens: str, fov: float) -> dict:
    return dict(lens="fisheye", fisheye_fov_deg=fov) if lens != "pinhole" else {}


def _run(scenario: str, seed: int, lens: str, fov: float, out: Path) -> tuple[dict, object, object]:
    """The run's record, its trajectory and the render's ground truth."""
    options = SimOptions(seed=seed, **SCENARIOS[scenario], **_lens_options(lens, fov))
    name = f"{scenario}-seed{seed}-{lens}"
    with tempfile.TemporaryDirectory() as tmp:
        generate(scenario, options, Path(tmp) / name, workers=2)
        record = _record(name, Path(tmp) / name, Settings(estimator="slam"), out)
        truth = open_dataset(Path(tmp) / name).ground_truth
    return {**record, "scenario": scenario, "seed": seed, "lens": lens}, read_trajectory(out / name / "trajectory.tum"), truth


def _common_frames_ate_percent(pinhole: tuple, fisheye: tuple) -> tuple[float, float]:
    """ATE (Sim3, as a share of the path) of each lens, each against its own render's truth, on
    only the frame times both tracked: the lenses start tracking at different moments (the
    pinhole late in a take-off, when the ground is already far), so their whole-run figures
    compare different stretches of the flight. (A survey's lines are spaced by the camera's
    footprint, so the two flights are not the same path: each needs its own truth.)"""
    (pinhole_trajectory, pinhole_truth), (fisheye_trajectory, fisheye_truth) = pinhole, fisheye
    pinhole_common, fisheye_common = associate(pinhole_trajectory, fisheye_trajectory, max_diff=1e-3)
    shares = []
    for estimate, truth in ((pinhole_common, pinhole_truth), (fisheye_common, fisheye_truth)):
        ref, est = associate(truth, estimate, max_diff=1e-3)
        aligned, _ = align_trajectory(ref, est, Alignment.SIM3)
        path = float(np.linalg.norm(np.diff(ref.positions, axis=0), axis=1).sum())
        shares.append(100 * float(np.sqrt(np.mean(ape_translation(ref, aligned) ** 2))) / path)
    return shares[0], shares[1]


def _comparison(scenario: str, rows: list[dict], fisheye: str, common: list[tuple[float, float]]) -> dict:
    """Means over the seeds; within the target when the fisheye's ATE share on the frames both
    lenses track is at most 1.2 x the pinhole's and its tracked share at least 0.8 x."""

    def mean(lens: str, field: str) -> float | None:
        values = [r[field] for r in rows if r["lens"] == lens]
        return None if any(v is None for v in values) else float(np.mean(values))

    pinhole_ate, fisheye_ate = mean("pinhole", "ate_path_percent"), mean(fisheye, "ate_path_percent")
    pinhole_tracked, fisheye_tracked = mean("pinhole", "tracked_percent"), mean(fisheye, "tracked_percent")
    pinhole_common, fisheye_common = (float(np.mean(values)) for values in zip(*common, strict=True))
    within = "yes" if fisheye_common <= (1 + TARGET) * pinhole_common and fisheye_tracked >= (1 - TARGET) * pinhole_tracked else "no"
    return {
        "scenario": f"{scenario} ({fisheye})",
        "seeds": " ".join(str(r["seed"]) for r in rows if r["lens"] == "pinhole"),
        "pinhole_ate_path_percent": pinhole_ate,
        "fisheye_ate_path_percent": fisheye_ate,
        "pinhole_tracked_percent": pinhole_tracked,
        "fisheye_tracked_percent": fisheye_tracked,
        "pinhole_common_ate_path_percent": pinhole_common,
        "fisheye_common_ate_path_percent": fisheye_common,
        "within_target": within,
    }


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--out", type=Path, default=Path("runs/camera_models"))
    parser.add_argument("--fov", type=float, default=150.0, help="fisheye diagonal field of view (degrees)")
    parser.add_argument("--seeds", nargs="*", type=int, default=[1, 2, 3], help="circle seeds (none: skip the circle)")
    parser.add_argument("--drone-seeds", nargs="*", type=int, default=[1], help="drone-flight seeds (none: skip the flight)")
    args = parser.parse_args()
    command = f"python bench/camera_models.py --out {args.out} --fov {args.fov:g} --seeds {' '.join(map(str, args.seeds))} --drone-seeds {' '.join(map(str, args.drone_seeds))}"
    print(f"command: {command}  ({platform.node()}, {platform.machine()})\n")
    results = Results("camera_models", command)
    fisheye = f"fisheye {args.fov:g} deg"
    runs = results.table("runs", RUN_COLUMNS, key=["scenario", "seed", "lens"], caption="`evp run` (SLAM, inline mapping) on each render, 640x380")
    comparisons = results.table("comparison", COMPARISON_COLUMNS, key=["scenario"], caption="Fisheye against pinhole: means over the seeds")
    print(runs.header())
    done: dict[str, list[dict]] = {}
    common: dict[str, list[tuple[float, float]]] = {}
    for scenario, seeds in (("circle-indoor", args.seeds), ("drone-flight", args.drone_seeds)):
        for seed in seeds:
            trajectories = []
            for lens in ("pinhole", fisheye):
                record, trajectory, truth = _run(scenario, seed, lens, args.fov, args.out)
                trajectories.append((trajectory, truth))
                done.setdefault(scenario, []).append(record)
                print(runs.add(record), flush=True)
            common.setdefault(scenario, []).append(_common_frames_ate_percent(*trajectories))
    print("\n" + comparisons.header())
    for scenario, rows in done.items():
        print(comparisons.add(_comparison(scenario, rows, fisheye, common[scenario])), flush=True)


if __name__ == "__main__":
    main()
