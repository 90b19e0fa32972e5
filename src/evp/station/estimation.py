"""The station's side of a session's estimator: wire messages to frames, poses back to the wire.

Each session's estimator runs in its own process (``evp.runtime.estimator_process``, which keeps
only the newest frame waiting); inside it, :func:`worker_main` decodes the images and drives the
one pipeline (the same ``make_estimator`` as ``evp run``), and a sink sends each answer back.
"""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np

from evp.geometry.transforms import poses_from_xyz_quat, quat_xyzw_from_matrices
from evp.pipeline import Sink
from evp.station.protocol import ImageMessage, Pose, ProtocolError
from evp.types import CameraModel, Frame, PoseEstimate


def pose_message(seq: int, estimate: PoseEstimate, reset_counter: int, processing_ms: float) -> Pose:
    """The wire form of an estimate: camera-to-world t and (qw, qx, qy, qz)."""
    qx, qy, qz, qw = quat_xyzw_from_matrices(estimate.T_world_cam[None, :3, :3])[0]
    covariance = None if estimate.covariance is None else [float(v) for v in np.asarray(estimate.covariance).reshape(-1)]
    return Pose(
        seq=seq,
        timestamp=estimate.timestamp,
        t=[float(v) for v in estimate.T_world_cam[:3, 3]],
        q=[float(qw), float(qx), float(qy), float(qz)],
        state=estimate.tracking_state.value,
        quality=int(estimate.quality),
        reset_counter=reset_counter,
        covariance=covariance,
        processing_ms=processing_ms,
    )


def pose_matrix(pose: Pose) -> np.ndarray:
    """T_world_cam (4x4) of a wire pose."""
    qw, qx, qy, qz = pose.q
    return poses_from_xyz_quat(np.array([pose.t]), np.array([[qx, qy, qz, qw]]))[0]


class PoseSender(Sink):
    """Sends each answer (or why a frame had none) back over the process's pipe."""

    def __init__(self, connection, estimator):
        self.connection = connection
        self.estimator = estimator

    def on_estimate(self, frame: Frame, estimate: PoseEstimate, elapsed_ms: float) -> None:
        self.connection.send(("pose", pose_message(frame.index, estimate, self.estimator.reset_counter, elapsed_ms)))

    def on_skip(self, frame: Frame | None, reason: str) -> None:
        self.connection.send(("error", ("corrupt_image", reason, None if frame is None else frame.index)))


def wire_frames(connection) -> Iterator[Frame]:
    """Frames from the station's image messages until it sends None or goes away; an image that
    cannot be decoded is answered with its protocol error and skipped."""
    from evp.station.protocol import image_pixels

    while True:
        try:
            message: ImageMessage | None = connection.recv()
        except EOFError:  # the station is gone
            return
        if message is None:
            return
        try:
            image = image_pixels(message)
        except ProtocolError as exc:
            connection.send(("error", (exc.code, exc.message, message.seq)))
            continue
        yield Frame(message.timestamp, image, index=message.seq, source="stream")


def worker_main(connection, camera: CameraModel, settings_json: str) -> None:
    """The estimator process (``EstimatorProcess``'s target): the pipeline over the wire's frames."""
    from evp.config import Settings
    from evp.pipeline import Pipeline
    from evp.run_setup import make_estimator

    settings = Settings.model_validate_json(settings_json)
    estimator = make_estimator(camera, settings)
    connection.send(("ready", None))
    Pipeline(estimator, [PoseSender(connection, estimator)]).run(wire_frames(connection))
    try:
        connection.send(("finished", None))
    except (BrokenPipeError, OSError):  # the station is gone
        pass
