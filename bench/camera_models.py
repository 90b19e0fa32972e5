"""`evp run` on rendered flights seen through the pinhole preset and through a fisheye at the same
resolution: does the SLAM engine hold its accuracy on a wide lens? Issue 29's target is the
fisheye figures (ATE as a share of the path, frames tracked) within 20 % of the pinhole ones.

Usage: python bench/camera_models.py [--out runs/camera_models] [--fov 150] [--seeds 1 2 3] [--drone-seeds 1]

Renders each scenario twice with `evp sim` (same motion, scene and noise; `--lens pinhole` with the
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
    ("fisheye within 20 %", "{within_target}"),
]


def _lens_options(lens: str, fov: float) -> dict:
    return dict(lens="fisheye", fisheye_fov_deg=fov) if lens != "pinhole" else {}


def _run(scenario: str, seed: int, lens: str, fov: float, out: Path) -> dict:
    options = SimOptions(seed=seed, **SCENARIOS[scenario], **_lens_options(lens, fov))
    name = f"{scenario}-seed{seed}-{lens}"
    with tempfile.TemporaryDirectory() as tmp:
        generate(scenario, options, Path(tmp) / name, workers=2)
        record = _record(name, Path(tmp) / name, Settings(estimator="slam"), out)
    return {**record, "scenario": scenario, "seed": seed, "lens": lens}


def _comparison(scenario: str, rows: list[dict], fisheye: str) -> dict:
    """Means over the seeds; within the target when the fisheye's ATE share is at most 1.2 x the
    pinhole's and its tracked share at least 0.8 x."""

    def mean(lens: str, field: str) -> float | None:
        values = [r[field] for r in rows if r["lens"] == lens]
        return None if any(v is None for v in values) else float(np.mean(values))

    pinhole_ate, fisheye_ate = mean("pinhole", "ate_path_percent"), mean(fisheye, "ate_path_percent")
    pinhole_tracked, fisheye_tracked = mean("pinhole", "tracked_percent"), mean(fisheye, "tracked_percent")
    within = None
    if None not in (pinhole_ate, fisheye_ate):
        within = "yes" if fisheye_ate <= (1 + TARGET) * pinhole_ate and fisheye_tracked >= (1 - TARGET) * pinhole_tracked else "no"
    return {
        "scenario": f"{scenario} ({fisheye})",
        "seeds": " ".join(str(r["seed"]) for r in rows if r["lens"] == "pinhole"),
        "pinhole_ate_path_percent": pinhole_ate,
        "fisheye_ate_path_percent": fisheye_ate,
        "pinhole_tracked_percent": pinhole_tracked,
        "fisheye_tracked_percent": fisheye_tracked,
        "within_target": within,
    }


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--out", type=Path, default=Path("runs/camera_models"))
    parser.add_argument("--fov", type=float, default=150.0, help="fisheye diagonal field of view (degrees)")
    parser.add_argument("--seeds", nargs="+", type=int, default=[1, 2, 3], help="circle seeds")
    parser.add_argument("--drone-seeds", nargs="+", type=int, default=[1])
    args = parser.parse_args()
    command = f"python bench/camera_models.py --out {args.out} --fov {args.fov:g} --seeds {' '.join(map(str, args.seeds))} --drone-seeds {' '.join(map(str, args.drone_seeds))}"
    print(f"command: {command}  ({platform.node()}, {platform.machine()})\n")
    results = Results("camera_models", command)
    fisheye = f"fisheye {args.fov:g} deg"
    runs = results.table("runs", RUN_COLUMNS, key=["scenario", "seed", "lens"], caption="`evp run` (SLAM, inline mapping) on each render, 640x380")
    comparisons = results.table("comparison", COMPARISON_COLUMNS, key=["scenario"], caption="Fisheye against pinhole: means over the seeds")
    print(runs.header())
    done: dict[str, list[dict]] = {}
    for scenario, seeds in (("circle-indoor", args.seeds), ("drone-flight", args.drone_seeds)):
        for seed in seeds:
            for lens in ("pinhole", fisheye):
                record = _run(scenario, seed, lens, args.fov, args.out)
                done.setdefault(scenario, []).append(record)
                print(runs.add(record), flush=True)
    print("\n" + comparisons.header())
    for scenario, rows in done.items():
        print(comparisons.add(_comparison(scenario, rows, fisheye)), flush=True)


if __name__ == "__main__":
    main()
