"""What every pose estimator offers the pipeline, the CLI and the base station."""

from __future__ import annotations

from typing import Protocol, runtime_checkable

import numpy as np

from evp.types import CameraModel, Frame, PoseEstimate


class Estimator(Protocol):
    def feed(self, frame: Frame) -> PoseEstimate:
        """Estimate the camera pose for one frame (frames must arrive in time order)."""
        ...


@runtime_checkable
class Refining(Protocol):
    """An estimator that can improve its whole trajectory once every frame is in (offline runs:
    SLAM through its bundle-adjusted keyframes, a photo survey adjusted as a whole)."""

    def refined_trajectory(self) -> tuple[np.ndarray, np.ndarray]:
        """Timestamps (N,) and ``T_world_cam`` (N, 4, 4) of the frames it localised."""
        ...


@runtime_checkable
class SelfCalibrating(Protocol):
    """An estimator that estimates part of the lens model from the images themselves."""

    lens: CameraModel | None  # the lens model it estimated (after ``refined_trajectory`` for a survey); None if none
