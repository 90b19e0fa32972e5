"""What every pose estimator offers the pipeline, the CLI and the base station."""

from __future__ import annotations

from typing import Protocol

from evp.types import Frame, PoseEstimate


class Estimator(Protocol):
    def feed(self, frame: Frame) -> PoseEstimate:
        """Estimate the camera pose for one frame (frames must arrive in time order)."""
        ...
