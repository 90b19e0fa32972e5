"""How well a rendered run's motion fixes the metric scale: VINS-Mono's linear visual-inertial
alignment (``evp.fusion.visual_inertial_init``) and the maximum-likelihood inertial refinement
seeded by it (``evp.fusion.inertial_refinement``, ORB-SLAM3's inertial-only optimisation) over
the whole run, at several keyframe intervals, on the truth's camera poses and, when given, on an
estimator's trajectory.

Usage: python bench/scale_observability.py --dataset RENDER [--trajectory TUM] [--intervals 0.1 0.25 0.5 1]

On the truth's poses (metres) an unbiased alignment returns 1 at every interval; on a
trajectory, the Sim3 scale that aligns it to the truth (printed beside). The spread says what the
motion leaves undetermined: on the indoor circle a body-frame accelerometer bias along the
centripetal axis is indistinguishable from scale (docs/decisions.md). Prints one row per case and
interval; needs a render with an IMU and ground truth (e.g. one kept by
bench/navigation_rendered.py in its --out).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import yaml
from results import Results

from evp.config import NavigationSettings
from evp.eval.association import associate
from evp.eval.metrics import Alignment, align_trajectory
from evp.fusion.inertial_refinement import refine_inertial
from evp.fusion.visual_inertial_init import initialise_visual_inertial
from evp.io.registry import open_dataset
from evp.io.trajectory import read_trajectory
from evp.types import Trajectory

TRUTH_POSITION_SIGMA_M = 1e-3  # the refinement's position prior on the truth's poses (exact: as small as stays well conditioned)
COLUMNS = [
    ("render", "{render}"),
    ("poses", "{poses}"),
    ("Sim3 scale to the truth", "{truth_scale:.4f}"),
    ("keyframe interval (s)", "{interval_s:g}"),
    ("keyframes", "{keyframes}"),
    ("alignment's scale", "{scale:.4f}"),
    ("sigma", "{sigma_percent:.2f} %"),
    ("scale error", "{error_percent:+.1f} %"),
    ("refined scale error", "{refined_error_percent:+.1f} %"),
    ("its sigma", "{refined_sigma_percent:.2f} %"),
]


def _render_name(folder: Path) -> str:
    """The scenario and seed from an `evp sim` render's sim.yaml, else the folder's name."""
    described = folder / "sim.yaml"
    if not described.exists():
        return folder.name
    sim = yaml.safe_load(described.read_text())
    return f"{sim['scenario']} seed {sim['options']['seed']} ({sim['duration_s']:g} s)"


def _every(trajectory: Trajectory, interval_s: float) -> list[tuple[float, np.ndarray]]:
    """(timestamp, pose) at least ``interval_s`` apart, from the first."""
    chosen, last = [], -np.inf
    for stamp, pose in zip(trajectory.timestamps, trajectory.poses, strict=True):
        if stamp - last >= interval_s - 1e-9:
            chosen.append((float(stamp), pose))
            last = stamp
    return chosen


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--dataset", type=Path, required=True)
    parser.add_argument("--trajectory", type=Path, help="an estimator's trajectory.tum / trajectory_visual.tum of the same render")
    parser.add_argument("--intervals", nargs="+", type=float, default=[0.1, 0.25, 0.5, 1.0])
    args = parser.parse_args()
    dataset = open_dataset(args.dataset)
    imu = list(dataset.imu)
    settings = NavigationSettings(vi_init_max_scale_sigma=1.0)  # report every answer, however uncertain
    cases = [("truth's camera poses", dataset.ground_truth, 1.0, TRUTH_POSITION_SIGMA_M)]
    if args.trajectory:
        estimate = read_trajectory(args.trajectory)
        _, transform = align_trajectory(*associate(dataset.ground_truth, estimate, 0.01), Alignment.SIM3)
        cases.append((f"estimate ({args.trajectory.name})", estimate, float(transform.scale), settings.vi_refine_position_sigma_m))
    command = f"python bench/scale_observability.py --dataset {args.dataset}" + (f" --trajectory {args.trajectory}" if args.trajectory else "")
    table = Results("scale_observability", command).table(
        "alignments", COLUMNS, key=["render", "poses", "interval_s"], caption="VINS-Mono's linear alignment and the inertial refinement over the whole run"
    )
    print(table.header())
    for name, trajectory, truth_scale, position_sigma in cases:
        for interval in args.intervals:
            keyframes = _every(trajectory, interval)
            result = initialise_visual_inertial(keyframes, imu, dataset.T_body_cam, settings)
            record = {"render": _render_name(args.dataset), "poses": name, "truth_scale": truth_scale, "interval_s": interval, "keyframes": len(keyframes)}
            if result.observable:
                error = 100 * (result.scale / truth_scale - 1)
                record |= {"scale": result.scale, "sigma_percent": 100 * result.scale_sigma, "error_percent": error}
                refined = refine_inertial(keyframes, imu, dataset.T_body_cam, result, settings, position_sigma)
                if refined.observable:
                    record |= {"refined_error_percent": 100 * (refined.scale / truth_scale - 1), "refined_sigma_percent": 100 * refined.scale_sigma}
            print(table.add(record), flush=True)


if __name__ == "__main__":
    main()
