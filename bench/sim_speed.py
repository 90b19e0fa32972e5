"""Simulator speed: planar rendering frames/s on one core, and the wall time of a 5-minute 30 fps flight.

Usage: python bench/sim_speed.py [--skip-flight]
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


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--skip-flight", action="store_true")
    args = parser.parse_args()
    cv2.setNumThreads(1)
    print(f"command: python bench/sim_speed.py  ({platform.node()}, {os.cpu_count()} cores; CPU time of one process, OpenCV single-threaded)\n")
    print("| what (640x380, nexus5x camera) | frames/s on one core |")
    print("|---|---|")
    flat = SimOptions(relief=False, duration_s=300.0)
    print(f"| planar ground, geometry + texture only | {_one_core_fps('drone-flight', flat, False):.0f} |")
    print(f"| planar ground, with blur, exposure, noise | {_one_core_fps('drone-flight', flat, True):.0f} |")
    print(f"| ground with buildings and trees | {_one_core_fps('drone-flight', SimOptions(duration_s=300.0), False):.0f} |")
    print(f"| wheel robot room (walls, furniture) | {_one_core_fps('wheel-robot-room', SimOptions(), False):.0f} |")
    if args.skip_flight:
        return
    print("\n| 5-minute 30 fps drone flight, written to disk | wall time (s) | frames |")
    print("|---|---|---|")
    for label, options in (("flat ground, 2 workers", SimOptions(relief=False)), ("with relief, 2 workers", SimOptions())):
        out = Path(tempfile.mkdtemp(prefix="evp-sim-bench-"))
        start = time.perf_counter()
        result = generate("drone-flight", options, out, workers=2)
        print(f"| {label} | {time.perf_counter() - start:.1f} | {result.frames} |")
        shutil.rmtree(out)


if __name__ == "__main__":
    main()
