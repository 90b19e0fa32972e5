"""SLAM on rendered 5-minute drone flights (seed 002's shape: take-off, climb to 60 m, lawnmower
survey at 6 m/s, landing), with local mapping in its own thread as it runs live: does it hold for
a whole flight, and does memory stay bounded?

Usage: python bench/long_flight.py [--duration 300] [--textures rich low] [--out runs/long_flight]

Prints per flight: the share of frames tracked (trajectory.tum; live) and when the first pose is
answered, losses, ATE (Sim3) in metres and as a share of the path, keyframes and map points, the
largest keyframe queue, tracking and mapping milliseconds, wall time against flight time, and
resident memory at the end with its growth per minute of flight (to judge a 10-minute flight).
`evp run`'s outputs and plots go to `--out`. Needs no shared data; renders each flight first,
then runs at about 0.9x the flight's time on two cores.
"""

from __future__ import annotations

import argparse
import platform
import resource
import tempfile
import time
from pathlib import Path

import numpy as np
from results import Results

from evp.config import Settings
from evp.io.registry import open_dataset
from evp.io.run_outputs import write_outputs
from evp.pipeline import run_dataset
from evp.run_setup import camera_for, make_estimator, resolve_settings
from evp.sim.generate import generate
from evp.sim.scenarios import SimOptions


def _rss_mb() -> float:
    with open("/proc/self/statm") as statm:
        return int(statm.read().split()[1]) * resource.getpagesize() / 2**20


def _losses(states: list) -> int:
    tracked = np.array([s.tracked for s in states])
    return int(np.sum(tracked[:-1] & ~tracked[1:]))


COLUMNS = [
    ("texture", "{texture}"),
    ("frames", "{frames}"),
    ("tracked (trajectory.tum; live)", "{tracked_percent:.1f} %; {tracked_live_percent:.1f} %"),
    ("first answered live (s)", "{first_answered_s:.1f}"),
    ("losses", "{losses}"),
    ("ATE Sim3 (m)", "{ate_m:.2f}"),
    ("path (m)", "{path_m:.0f}"),
    ("ATE / path", "{ate_path_percent:.2f} %"),
    ("keyframes", "{keyframes}"),
    ("map points", "{map_points}"),
    ("max keyframe queue", "{keyframe_queue_max}"),
    ("tracking ms median / p95", "{tracking_ms_median:.1f} / {tracking_ms_p95:.1f}"),
    ("mapping ms/keyframe", "{mapping_ms_median:.0f}"),
    ("wall / flight time", "{wall_to_flight:.2f}"),
    ("RSS end (MB)", "{rss_end_mb:.0f}"),
    ("RSS growth (MB/min)", "{rss_growth_mb_per_min:.1f}"),
]


def _flight_record(texture: str, duration: float, out: Path, tmp: Path) -> dict:
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
    return {
        "texture": texture,
        "duration_s": duration,
        "frames": len(states),
        "tracked_percent": 100 * metrics["tracked_fraction"],
        "tracked_live_percent": 100 * metrics["tracked_live_frames"] / len(states),
        "first_answered_s": first / 30.0 if first is not None else None,
        "losses": _losses(states),
        "ate_m": metrics.get("rmse"),
        "path_m": metrics.get("reference_path_length_m"),
        "ate_path_percent": 100 * ate / path,
        "keyframes": len(estimator.map.keyframes),
        "map_points": len(estimator.map.points),
        "keyframe_queue_max": estimator.mapping.max_queue,
        "tracking_ms_median": float(np.median(result.tracking_ms)),
        "tracking_ms_p95": float(np.percentile(result.tracking_ms, 95)),
        "mapping_ms_median": float(np.median(mapping)) if mapping else None,
        "wall_to_flight": wall / duration,
        "rss_end_mb": rss_end,
        "rss_growth_mb_per_min": (rss_end - rss_start) / (duration / 60.0),
    }


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--duration", type=float, default=300.0)
    parser.add_argument("--textures", nargs="+", default=["rich", "low"])
    parser.add_argument("--out", type=Path, default=Path("runs/long_flight"))
    args = parser.parse_args()
    command = f"python bench/long_flight.py --duration {args.duration:g} --textures {' '.join(args.textures)} --out {args.out}"
    print(f"command: {command}  ({platform.node()}, {platform.machine()})\n")
    table = Results("long_flight", command).table("flights", COLUMNS, key=["texture", "duration_s"], caption="Rendered drone flights, mapping in its thread")
    print(table.header())
    with tempfile.TemporaryDirectory() as tmp:
        for texture in args.textures:
            print(table.add(_flight_record(texture, args.duration, args.out, Path(tmp))), flush=True)


if __name__ == "__main__":
    main()
