"""What a real camera adds to the ideal image: motion blur, exposure changes, noise, rolling shutter."""

from __future__ import annotations

import math

import cv2
import numpy as np

from evp.sim.scenarios import Scenario, SimOptions
from evp.sim.world import Renderer, ray_distance

ELECTRONS_PER_GREY_LEVEL = 4.0  # sets the shot noise: variance = signal / this
MAX_BLUR_SAMPLES = 8


def exposure_gain(t: float, options: SimOptions, seed: int) -> float:
    """Auto-exposure wandering: slow sinusoids with a seeded phase, amplitude ``gain_variation``."""
    phase = (seed * 0.618) % 1.0 * 2 * math.pi
    return 1.0 + options.gain_variation * (0.7 * math.sin(2 * math.pi * t / 9.0 + phase) + 0.3 * math.sin(2 * math.pi * t / 2.3 + 2 * phase))


def _blur_samples(scenario: Scenario, t: float, options: SimOptions) -> int:
    """Sub-frames needed so that consecutive ones move less than half a pixel."""
    if options.exposure_s <= 0:
        return 1
    poses = scenario.camera_poses(np.array([t - options.exposure_s / 2, t + options.exposure_s / 2]))
    rotation = np.linalg.norm(np.linalg.inv(poses[0][:3, :3]) @ poses[1][:3, :3] - np.eye(3))
    depth = ray_distance(scenario.scene, poses[0][:3, 3], poses[0][:3, 2])
    translation = np.linalg.norm(poses[1][:3, 3] - poses[0][:3, 3]) / max(min(depth, 1e6), 0.05)
    pixels = (rotation + translation) * scenario.camera.fx
    return int(min(MAX_BLUR_SAMPLES, max(1, math.ceil(pixels / 0.5))))


def render_frame(renderer: Renderer, scenario: Scenario, t: float, options: SimOptions, frame_seed: int) -> np.ndarray:
    """The image a camera records at mid-exposure time ``t``."""
    camera = scenario.camera
    offsets = np.linspace(-options.exposure_s / 2, options.exposure_s / 2, _blur_samples(scenario, t, options)) if options.exposure_s > 0 else [0.0]
    accumulated = np.zeros((camera.height, camera.width), np.float32)
    for offset in np.atleast_1d(offsets):
        if options.rolling_shutter_s > 0:
            row_times = t + offset + (np.arange(camera.height) / (camera.height - 1) - 0.5) * options.rolling_shutter_s
            image = renderer.render(np.eye(4), row_poses=scenario.camera_poses(row_times))
        else:
            image = renderer.render(scenario.camera_poses(np.array([t + offset]))[0])
        accumulated += image
    image = accumulated * np.float32(exposure_gain(t, options, options.seed) / len(np.atleast_1d(offsets)))
    if options.noise_sigma > 0:
        # read noise + shot noise; OpenCV's generator (seeded per frame) is 3x faster than NumPy's here
        noise = np.empty_like(image)
        cv2.setRNGSeed(frame_seed)
        cv2.randn(noise, 0.0, 1.0)
        image += noise * np.sqrt(np.float32(options.noise_sigma**2) + np.maximum(image, 0) / np.float32(ELECTRONS_PER_GREY_LEVEL))
    return np.clip(image + 0.5, 0, 255).astype(np.uint8)
