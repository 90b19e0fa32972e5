"""A flight that starts where an earlier one mapped (issue 31, seed 002's geotagged keypoints): the
second flight loads the first's saved map, relocalises in it and is georeferenced at once, with
GPS jammed from take-off.

Usage: python bench/saved_map_flight.py [--duration 90] [--second-duration 60] [--fps 10]
       [--altitude 40] [--area 100 60] [--takeoff 20 12] [--keep DIR]

Renders `evp sim drone-flight` twice over the same world (seed 0, 640x380, lawnmower over
``--area`` at ``--altitude``):

1. the first flight, taking off at the world's origin, with GPS: run as `evp run` does (SLAM, the
   navigation stage georeferenced by GPS, the refined pass) and its outputs written, map.npz
   with the map's georeference;
2. the second flight, taking off ``--takeoff`` metres away, GPS jammed for the whole flight (no
   fix at all), run from the first's map.npz (`slam.map`, `evp run --map`): SLAM relocalises in
   the map, the navigation stage starts from the map's georeference.

Reports for the second flight the time from SLAM's first relocalisation to the first answer that is
georeferenced, and the horizontal error of the live georeferenced answers against the truth (no
alignment; ENU at the first flight's take-off point, the truth converted through WGS-84), mean and
max, from georeferencing to the end of the cruise (the landing, straight down onto texture out of
focus, is left out as in bench/gps_spoofing.py). The first flight's map georeference (keyframes,
RMS residual) and its own horizontal error (its refined pass, all its georeferenced frames: the
`horizontal_error_mean_m` of its metrics.json) are in the row too. The second flight's ground is
the first's (`ground_half_m`: the texture depends on its size). With ``--keep DIR`` the renders and
the first run found there are used again.
"""

from __future__ import annotations

import argparse
import json
import platform
import shutil
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from results import Results  # noqa: E402

from evp.config import Settings  # noqa: E402
from evp.eval.evaluate import evaluate  # noqa: E402
from evp.experiments.seed002_flights import AERIAL_NAVIGATION, CLIMB_M_S  # noqa: E402
from evp.io.map_files import read_map_georeference  # noqa: E402
from evp.io.navigation_outputs import georeferenced_trajectory, truth_in_enu  # noqa: E402
from evp.io.registry import open_dataset  # noqa: E402
from evp.io.run_outputs import write_outputs  # noqa: E402
from evp.pipeline import run_dataset  # noqa: E402
from evp.run_setup import camera_for, make_estimator, navigation_on_refined, navigation_stage, resolve_settings  # noqa: E402
from evp.sim import sensors  # noqa: E402
from evp.sim.generate import generate  # noqa: E402
from evp.sim.scenarios import SimOptions, build_scenario  # noqa: E402

COLUMNS = [
    ("flights (s)", "{first_s:.0f} + {second_s:.0f}"),
    ("map: keyframes / fit RMS (m)", "{map_keyframes} / {map_residual_m:.2f}"),
    ("first relocalised at (s)", "{relocalised_s:.1f}"),
    ("relocalised to georeferenced (s)", "{to_georeferenced_s:.2f}"),
    ("horizontal error mean / max (m)", "{mean_m:.2f} / {max_m:.2f}"),
    ("first flight (GPS) mean (m)", "{first_mean_m:.2f}"),
    ("frames", "{frames}"),
]


def _options(duration: float, fps: float, altitude: float, area: tuple[float, float], takeoff=(0.0, 0.0), gps=None, ground_half_m=None) -> SimOptions:
    gps = gps or sensors.GpsConfig()
    return SimOptions(duration_s=duration, fps=fps, seed=0, altitude_m=altitude, area_m=area, takeoff_m=takeoff, gps=gps, ground_half_m=ground_half_m)


def _render(folder: Path, options: SimOptions) -> Path:
    if (folder / "sim.yaml").exists():
        print(f"{folder.name}: rendered before, kept", flush=True)
        return folder
    print(f"rendering {folder.name}: {options.duration_s:g} s at {options.fps:g} fps, take-off at {options.takeoff_m}", flush=True)
    generate("drone-flight", options, folder, workers=2)
    return folder


def _settings(dataset, saved_map: Path | None = None) -> Settings:
    settings = resolve_settings(Settings(estimator="slam"), dataset)
    settings.navigation = settings.navigation.model_copy(update=AERIAL_NAVIGATION)
    if saved_map is not None:
        settings.slam = settings.slam.model_copy(update={"map": str(saved_map)})
    return settings


def _run(dataset, settings: Settings):
    """SLAM and the navigation stage over the dataset, as `evp run` drives them."""
    estimator = make_estimator(camera_for(dataset, settings), settings, dataset)
    stage = navigation_stage(dataset, settings, estimator)
    result = run_dataset(dataset, estimator, stages=[stage])
    return estimator, stage, result


def _horizontal_errors(stage, result, dataset, settings, until: float) -> tuple[np.ndarray, np.ndarray]:
    truth = truth_in_enu(dataset, stage.enu_frame)
    none = evaluate(truth, georeferenced_trajectory(result), settings.eval.model_copy(update={"align": "none"}))
    times, errors = none.ref.timestamps, none.ape_translation_xy
    return times[times <= until], errors[times <= until]


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--duration", type=float, default=90.0, help="the first flight (s)")
    parser.add_argument("--second-duration", type=float, default=60.0, help="the second flight (s)")
    parser.add_argument("--fps", type=float, default=10.0)
    parser.add_argument("--altitude", type=float, default=40.0)
    parser.add_argument("--area", type=float, nargs=2, default=(100.0, 60.0))
    parser.add_argument("--takeoff", type=float, nargs=2, default=(20.0, 12.0), help="the second flight's take-off point (m from the first's)")
    parser.add_argument("--keep", type=Path, help="keep the renders and the first run's outputs here")
    args = parser.parse_args()
    command = (
        f"python bench/saved_map_flight.py --duration {args.duration:g} --second-duration {args.second_duration:g} --fps {args.fps:g} "
        f"--altitude {args.altitude:g} --area {args.area[0]:g} {args.area[1]:g} --takeoff {args.takeoff[0]:g} {args.takeoff[1]:g}"
    )
    print(f"command: {command}  ({platform.node()}, {platform.machine()})\n")
    table = Results("saved_map_flight", command).table(
        "flights",
        COLUMNS,
        key=["first_s", "second_s"],
        caption="Second rendered drone flight from the first's saved map, GPS jammed from take-off: errors against the truth, no alignment",
    )
    area, takeoff = tuple(args.area), tuple(args.takeoff)
    with tempfile.TemporaryDirectory() as tmp:
        root = args.keep or Path(tmp)
        root.mkdir(parents=True, exist_ok=True)
        first_options = _options(args.duration, args.fps, args.altitude, area)
        first = open_dataset(_render(root / "first", first_options))
        # the second flight over the first's world: the ground's size (and so its texture) is the first's
        ground = build_scenario("drone-flight", first_options).scene.quads[0]
        jammed = sensors.GpsConfig(outages=[(0.0, args.second_duration + 10.0)])
        second_options = _options(args.second_duration, args.fps, args.altitude, area, takeoff, jammed, ground.size_u / 2)
        folder = _render(root / "second", second_options)
        if (folder / "mav0" / "gps0").exists():
            shutil.rmtree(folder / "mav0" / "gps0")  # not one fix: the receiver's log is empty, as a flight jammed from take-off leaves none
        second = open_dataset(folder)

        map_file = root / "first_run" / "map.npz"
        if not map_file.exists():  # a --keep folder holds the first run from before
            start = time.perf_counter()
            settings = _settings(first)
            estimator, stage, result = _run(first, settings)
            result.final_trajectory()
            refined = navigation_on_refined(first, settings, result.refined, live=result.estimates) if result.refined is not None and len(result.refined) >= 2 else None
            write_outputs(result, first, settings, root / "first_run", stage, refined)
            print(f"first flight: {time.perf_counter() - start:.0f} s, {stage.status}", flush=True)
        georeference = read_map_georeference(map_file)
        if georeference is None:
            raise SystemExit("the first flight's map was saved without a georeference: the run never held GPS long enough")
        first_metrics = json.loads((root / "first_run" / "metrics.json").read_text())["navigation"]
        landing = args.altitude / CLIMB_M_S + 2.0

        start = time.perf_counter()
        settings = _settings(second, map_file)
        estimator, stage, result = _run(second, settings)
        print(f"second flight: {time.perf_counter() - start:.0f} s, {stage.status}", flush=True)
        relocalised = estimator.saved_map.relocalised_at
        georeferenced = next((e.timestamp for e in result.estimates if e.georeferenced), None)
        if relocalised is None or georeferenced is None:
            raise SystemExit(f"the second flight never relocalised in the saved map or never georeferenced: {estimator.report().get('saved_map')}")
        times, errors = _horizontal_errors(stage, result, second, settings, second.frame_times[-1] - landing)
        t0 = second.frame_times[0]
        print(table.header())
        record = {
            "first_s": args.duration,
            "second_s": args.second_duration,
            "map_keyframes": georeference.keyframes,
            "map_residual_m": georeference.residual_m,
            "relocalised_s": relocalised - t0,
            "to_georeferenced_s": georeferenced - relocalised,
            "mean_m": float(errors.mean()),
            "max_m": float(errors.max()),
            "first_mean_m": first_metrics["horizontal_error_mean_m"],
            "frames": f"{len(times)} of {second.num_frames}",
        }
        print(table.add(record), flush=True)


if __name__ == "__main__":
    main()
