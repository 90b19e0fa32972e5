"""Relocalisation trials: a forced tracking loss (the lens covered) followed by a return to a
mapped place. Shared by the tests and bench/run_sequences.py (an experiment driving the system,
not part of it)."""

import numpy as np

from evp.pipeline import Pipeline
from evp.slam.system import SlamSystem
from evp.types import Frame, PoseEstimate, TrackingState


def cover_lens_then_revisit(
    slam: SlamSystem, frames: list[Frame], mapped: int, revisit: slice, views: list[np.ndarray] | None = None
) -> tuple[list[PoseEstimate], list[PoseEstimate]]:
    """Feed ``frames[:mapped]``, three blank frames (which must lose tracking), then
    ``frames[revisit]`` again with later timestamps (or ``views``: other images of those places,
    one per revisited frame). Returns the first pass's estimates and those of the revisit."""
    pipeline = Pipeline(slam)
    first = [pipeline.process(frame) for frame in frames[:mapped]]
    blank = np.full_like(frames[0].image, 128)
    t = frames[mapped - 1].timestamp
    for k in range(3):
        estimate = pipeline.process(Frame(t + 0.01 * (k + 1), blank, mapped + k))
    if estimate.tracking_state != TrackingState.LOST:
        raise RuntimeError("a covered lens did not lose tracking")
    images = views if views is not None else [frame.image for frame in frames[revisit]]
    again = [pipeline.process(Frame(t + 1.0 + 0.1 * k, image, mapped + 3 + k)) for k, image in enumerate(images)]
    return first, again


def relocalisation_error(
    first: list[PoseEstimate], again: list[PoseEstimate], revisit: slice, camera_turn: np.ndarray | None = None
) -> tuple[int, float, float] | None:
    """Index of the first RELOCALIZED answer in the revisit, and how far (map units, degrees) its
    pose is from the pose estimated for the same place on the first pass (turned by
    ``camera_turn``, a rotation in the camera's frame, when the revisit looked another way);
    None if it never relocalised."""
    states = [e.tracking_state for e in again]
    if TrackingState.RELOCALIZED not in states:
        return None
    index = states.index(TrackingState.RELOCALIZED)
    before = first[range(len(first))[revisit][index]].T_world_cam.copy()
    if camera_turn is not None:
        before[:3, :3] = before[:3, :3] @ camera_turn
    after = again[index].T_world_cam
    R = before[:3, :3].T @ after[:3, :3]
    angle = float(np.degrees(np.arccos(np.clip((np.trace(R) - 1) / 2, -1, 1))))
    return index, float(np.linalg.norm(before[:3, 3] - after[:3, 3])), angle
