"""What every pose estimator offers the pipeline, the CLI and the base station.

A base class rather than a bare protocol: each estimator states what it offers by overriding a
method, and inherits a documented default for the rest, so the pipeline never probes types or
attributes (``hasattr``/``isinstance``) to learn what an estimator can do.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from typing import Any

import numpy as np

from evp.types import CameraModel, Frame, PoseEstimate, TrackingState

# why a monocular estimator tracks nothing, said wherever a run ends without a tracked frame
NOT_INITIALISED_HINT = (
    "monocular initialisation needs two views with parallax between them: the camera must move "
    "sideways a few percent of the scene's distance (a standing or only turning camera never initialises)"
)


class Estimator(ABC):
    """A pose estimator fed one frame at a time, in time order."""

    reset_counter: int = 0  # bumped at each discontinuity (relocalisation, restart) consumers must know of
    # whether observe may be called from another thread while feed runs: the estimator keeps its
    # calls in order itself (one in another process or on a cluster's worker); live, an estimator
    # that observes without this is fed each frame under the pipeline's lock
    observes_while_feeding: bool = False
    lens: CameraModel | None = None  # the lens model it estimated from the images (a survey's self-calibration); None if none

    @abstractmethod
    def feed(self, frame: Frame) -> PoseEstimate:
        """Estimate the camera pose for one frame (frames must arrive in time order); a frame it
        cannot use raises an ``EvpError`` naming why (the pipeline skips it and goes on)."""

    @property
    def uses_telemetry(self) -> bool:
        """Whether :meth:`observe` does anything (an EKF-SLAM predicts with the wheels; SLAM takes
        no telemetry, so none need be given to it, or sent to it in another process)."""
        return type(self).observe is not Estimator.observe

    def observe(self, record: Any) -> None:
        """A telemetry record (IMU, wheels, GPS...), each before the first frame not older than it,
        in time order. Default: the estimator uses none (stages after it may)."""
        return None

    def settle(self) -> None:
        """Finish the work the last frame started (mapping its keyframe) now, after its answer is
        out; the next :meth:`feed` does it first otherwise. Default: nothing to do."""
        return None

    def finish(self) -> None:
        """End of the stream: wait for background work and release what the estimator started."""
        return None

    def close(self) -> None:
        """Release what the estimator started (threads, processes) without finishing its work: a
        run that failed part way. Safe to call after :meth:`finish`. Default: nothing started."""
        return None

    def refined_trajectory(self) -> tuple[np.ndarray, np.ndarray] | None:
        """Timestamps (N,) and ``T_world_cam`` (N, 4, 4) of the frames it localised, improved once
        every frame is in (SLAM through its bundle-adjusted keyframes, a photo survey adjusted as a
        whole); None when it offers nothing better than its live answers. Call after :meth:`finish`."""
        return None

    def keyframe_trajectory(self) -> tuple[np.ndarray, np.ndarray] | None:
        """Timestamps and ``T_world_cam`` of its keyframes; None for an estimator without a map."""
        return None

    def sparse_map(self) -> Any | None:
        """The map it built (``evp.slam.map.Map``), for map files; None for an estimator without one."""
        return None

    def timing(self) -> dict[str, Any]:
        """Its own timing figures: lists of per-frame or per-keyframe milliseconds, named as in
        timing.json (``tracking_ms`` when it can time tracking apart from background work)."""
        return {}

    def report(self) -> dict[str, Any]:
        """Events worth writing into a run's metrics (closed loops...), JSON-ready."""
        return {}


class GivenPoses(Estimator):
    """Answers each frame with the pose a trajectory already holds at its time, and ``LOST`` where
    it holds none (``NOT_INITIALIZED`` before its first pose): the pipeline's stages run again on poses estimated before (an offline run's
    refined trajectory, a test's or bench's truth). The images are not looked at. ``scene_depths``
    (one per pose, NaN where unknown) are answered as each estimate's ``scene_depth``."""

    def __init__(self, timestamps: np.ndarray, T_world_cam: np.ndarray, tolerance_s: float = 1e-6, scene_depths: np.ndarray | None = None):
        order = np.argsort(timestamps)
        self.timestamps = np.asarray(timestamps, float)[order]
        self.poses = np.asarray(T_world_cam, float).reshape(-1, 4, 4)[order]
        self.depths = None if scene_depths is None else np.asarray(scene_depths, float)[order]
        self.tolerance_s = tolerance_s

    def feed(self, frame: Frame) -> PoseEstimate:
        index = int(np.searchsorted(self.timestamps, frame.timestamp))
        nearest = min((i for i in (index - 1, index) if 0 <= i < len(self.timestamps)), key=lambda i: abs(self.timestamps[i] - frame.timestamp), default=None)
        if nearest is None or abs(self.timestamps[nearest] - frame.timestamp) > self.tolerance_s:
            started = len(self.timestamps) and frame.timestamp > self.timestamps[0]
            return PoseEstimate(frame.timestamp, np.eye(4), TrackingState.LOST if started else TrackingState.NOT_INITIALIZED)
        depth = None if self.depths is None or not np.isfinite(self.depths[nearest]) else float(self.depths[nearest])
        return PoseEstimate(frame.timestamp, self.poses[nearest].copy(), TrackingState.OK, 100, scene_depth=depth)
