"""Simulator speed: rendering frames per second on one core (planar ground, full camera effects,
ground with relief, the wheel-robot room), and the wall time of a 5-minute 30 fps drone flight
written to disk with two workers.

Usage: python bench/sim_speed.py [--skip-flight]

Prints the frames per second (CPU time of one process, OpenCV single-threaded) and, unless
`--skip-flight`, the flights' wall times. Needs no shared data.
"""

from __future__ import annotations

import argparse
import os
import platform
import shutil
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np
from results import Results

from evp.sim.camera_effects import render_frame
from evp.sim.generate import generate
from evp.sim.scenarios import SimOptions, build_scenario
from evp.sim.world import Renderer


def _one_core_fps(scenario_name: str, options: SimOptions, full_frame: bool) -> float:
    scenario = build_scenario(scenario_name, options)
    renderer = Renderer(scenario.camera, scenario.scene)
    times = np.linspace(scenario.motion.start + 0.3 * scenario.motion.duration, scenario.motion.end - 0.1 * scenario.motion.duration, 200)
    poses = scenario.camera_poses(times)
    start = time.process_time()
    for t, pose in zip(times, poses):
        if full_frame:
            render_frame(renderer, scenario, t, options, 0)
        else:
            renderer.render(pose)
    return len(times) / (time.process_time() - start)


RENDER_COLUMNS = [("what (640x380, nexus5x camera)", "{what}"), ("frames/s on one core", "{fps:.0f}")]
FLIGHT_COLUMNS = [("5-minute 30 fps drone flight, written to disk", "{flight}"), ("wall time (s)", "{wall_s:.1f}"), ("frames", "{frames}")]


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--skip-flight", action="store_true")
    args = parser.parse_args()
    cv2.setNumThreads(1)
    command = "python bench/sim_speed.py" + (" --skip-flight" if args.skip_flight else "")
    print(f"command: {command}  ({platform.node()}, {os.cpu_count()} cores; CPU time of one process, OpenCV single-threaded)\n")
    results = Results("sim_speed", command)
    rendering = results.table("rendering", RENDER_COLUMNS, key=["what"], caption="CPU time of one process, OpenCV single-threaded")
    print(rendering.header())
    flat = SimOptions(relief=False, duration_s=300.0)
    print(rendering.add({"what": "planar ground, geometry + texture only", "fps": _one_core_fps("drone-flight", flat, False)}))
    print(rendering.add({"what": "planar ground, with blur, exposure, noise", "fps": _one_core_fps("drone-flight", flat, True)}))
    print(rendering.add({"what": "ground with buildings and trees", "fps": _one_core_fps("drone-flight", SimOptions(duration_s=300.0), False)}))
    print(rendering.add({"what": "wheel robot room (walls, furniture)", "fps": _one_core_fps("wheel-robot-room", SimOptions(), False)}))
    if args.skip_flight:
        return
    flights = results.table("flights", FLIGHT_COLUMNS, key=["flight"])
    print("\n" + flights.header())
    for label, options in (("flat ground, 2 workers", SimOptions(relief=False)), ("with relief, 2 workers", SimOptions())):
        out = Path(tempfile.mkdtemp(prefix="evp-sim-bench-"))
        start = time.perf_counter()
        result = generate("drone-flight", options, out, workers=2)
        print(flights.add({"flight": label, "wall_s": time.perf_counter() - start, "frames": result.frames}))
        shutil.rmtree(out)


if __name__ == "__main__":
    main()
