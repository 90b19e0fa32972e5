"""Training images for the bag-of-words vocabulary, rendered by the simulator.

EVP cannot download a vocabulary and the public datasets' licences do not let one trained on them
ship in an MIT package, so the shipped vocabulary is trained on EVP's own renders: the scenes its
users fly (nadir drone surveys over paved and grass ground with buildings and trees, low and high,
indoor floors, a ground robot's forward view of a room, a marker field), with each scene's camera,
noise and blur. Frames are taken at spread times, so views differ in place, height and heading.
Generalisation to real images is measured in ``bench/place_recognition.py``.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np

from evp.sim.camera_effects import render_frame
from evp.sim.scenarios import SimOptions, build_scenario
from evp.sim.world import Renderer


@dataclass(frozen=True)
class TrainingScene:
    scenario: str
    options: dict

    @property
    def label(self) -> str:
        """How a vocabulary's notes name the scene it was trained on."""
        return f"{self.scenario} {self.options}"


TRAINING_SCENES = (
    TrainingScene("drone-flight", {"texture": "rich", "altitude_m": 60.0, "seed": 11}),
    TrainingScene("drone-flight", {"texture": "rich", "altitude_m": 30.0, "seed": 12, "camera": "phone_1280x720"}),
    TrainingScene("drone-flight", {"texture": "low", "altitude_m": 40.0, "seed": 13}),
    TrainingScene("drone-square-loops", {"seed": 14, "camera": "global_752x480"}),
    TrainingScene("drone-field-loops", {"seed": 15}),
    TrainingScene("circle-indoor", {"seed": 16}),
    TrainingScene("circle-indoor", {"seed": 17, "texture": "rich", "camera": "global_752x480"}),
    TrainingScene("wheel-robot-room", {"seed": 18}),
    TrainingScene("wheel-robot-room", {"seed": 19, "camera": "phone_1280x720"}),
    TrainingScene("marker-field", {"seed": 20}),
)


def training_images(frames_per_scene: int = 40, scenes: tuple[TrainingScene, ...] = TRAINING_SCENES) -> Iterator[tuple[str, object, np.ndarray]]:
    """(scene label, camera model, grey image) for ``frames_per_scene`` frames of each scene, at
    times spread evenly over the scene's duration (the first and last 5 % left out: on the ground)."""
    for scene in scenes:
        options = SimOptions(**scene.options)
        scenario = build_scenario(scene.scenario, options)
        renderer = Renderer(scenario.camera, scenario.scene)
        start, end = scenario.motion.start, scenario.motion.end
        span = end - start
        for index, t in enumerate(np.linspace(start + 0.05 * span, end - 0.05 * span, frames_per_scene)):
            yield scene.label, scenario.camera, render_frame(renderer, scenario, float(t), options, frame_seed=index)
