"""The SLAM engine on rendered 5-minute drone flights (seed 002's shape: take-off, climb to 60 m,
lawnmower survey at 6 m/s, landing), with local mapping in its own thread as it runs live.

Usage: python bench/long_flight.py [--duration 300] [--textures rich low] [--out runs/long_flight]

Per flight: tracked share of frames and when tracking first starts, losses, ATE (Sim3) in metres
and as a share of the path, keyframes and map points, the largest keyframe-queue length seen by
the mapping thread, tracking and mapping milliseconds, the wall time against the flight time,
and resident memory at the end with its growth per minute of flight (to judge a 10-minute
flight). ``evp run``'s outputs and plots for each flight go to ``--out``.
"""

from __future__ import annotations

import argparse
import platform
import resource
import tempfile
import time
from pathlib import Path

import numpy as np

from evp.config import Settings
from evp.io.registry import open_dataset
from evp.pipeline import TRACKED_STATES, run_dataset, write_outputs
from evp.run_setup import camera_for, make_estimator, resolve_settings
from evp.sim.generate import generate
from evp.sim.scenarios import SimOptions


def _rss_mb() -> float:
    with open("/proc/self/statm") as statm:
        return int(statm.read().split()[1]) * resource.getpagesize() / 2**20


def _losses(states: list) -> int:
    tracked = np.array([s in TRACKED_STATES for s in states])
    return int(np.sum(tracked[:-1] & ~tracked[1:]))


def _flight_row(texture: str, duration: float, out: Path, tmp: Path) -> str:
    generate("drone-flight", SimOptions(duration_s=duration, fps=30.0, seed=1, altitude_m=60.0, texture=texture), tmp / texture, workers=2)
    dataset = open_dataset(tmp / texture)
    settings = resolve_settings(Settings(estimator="slam"), dataset)
    settings.slam.mapping = "thread"
    estimator = make_estimator(camera_for(dataset, settings), settings, dataset)
    rss_start = _rss_mb()
    start = time.perf_counter()
    result = run_dataset(dataset, estimator)
    wall = time.perf_counter() - start
    rss_end = _rss_mb()
    metrics = write_outputs(result, dataset, settings, out / f"drone-flight-{texture}")
    states = [e.tracking_state for e in result.estimates]
    first = result.init_frame
    ate = metrics.get("rmse", float("nan"))
    path = metrics.get("reference_path_length_m", float("nan"))
    mapping = estimator.mapping_ms
    return (
        f"| {texture} | {len(states)} | {100 * metrics['tracked_fraction']:.1f} %; {100 * metrics['tracked_live_frames'] / len(states):.1f} % | {first / 30.0 if first is not None else float('nan'):.1f} | {_losses(states)} "
        f"| {ate:.2f} | {path:.0f} | {100 * ate / path:.2f} % | {len(estimator.map.keyframes)} | {len(estimator.map.points)} | {estimator.mapping.max_queue} "
        f"| {np.median(result.tracking_ms):.1f} / {np.percentile(result.tracking_ms, 95):.1f} | {np.median(mapping) if mapping else float('nan'):.0f} "
        f"| {wall / duration:.2f} | {rss_end:.0f} | {(rss_end - rss_start) / (duration / 60.0):.1f} |"
    )


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--duration", type=float, default=300.0)
    parser.add_argument("--textures", nargs="+", default=["rich", "low"])
    parser.add_argument("--out", type=Path, default=Path("runs/long_flight"))
    args = parser.parse_args()
    print(
        f"command: python bench/long_flight.py --duration {args.duration:g} --textures {' '.join(args.textures)} --out {args.out}  ({platform.node()}, {platform.machine()})\n"
    )
    print(
        "| texture | frames | tracked (trajectory.tum; live) | first answered live (s) | losses | ATE Sim3 (m) | path (m) | ATE / path | keyframes | map points "
        "| max keyframe queue | tracking ms median / p95 | mapping ms/keyframe | wall / flight time | RSS end (MB) | RSS growth (MB/min) |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    with tempfile.TemporaryDirectory() as tmp:
        for texture in args.textures:
            print(_flight_row(texture, args.duration, args.out, Path(tmp)), flush=True)


if __name__ == "__main__":
    main()
