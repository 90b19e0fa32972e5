"""The station's side of a session's estimator: wire messages to frames, poses back to the wire.

Each session's estimator runs in its own process (``evp.runtime.estimator_process``); inside it,
:func:`worker_main` drives the one pipeline (the same ``make_estimator`` as ``evp run``, with the
same navigation stage when the mobile station sends its IMU's extrinsic) through
:class:`evp.runtime.live_pipeline.LivePipeline`: telemetry to the stages as it arrives, each frame
answered at once with the current estimate, vision on the newest frame in a worker thread.
"""

from __future__ import annotations

import math
import sys
import threading
import time
from dataclasses import asdict

import numpy as np

from evp.geometry.transforms import poses_from_xyz_quat, quat_xyzw_from_matrices
from evp.pipeline import Pipeline, Sink
from evp.runtime.live_pipeline import LiveAnswer, LivePipeline, estimator_jumps
from evp.runtime.vision_process import ClusterEstimator, EstimatorServer, RemoteEstimator, ThreadPriority, serve_estimator
from evp.station.protocol import Pose, ProtocolError, image_pixels
from evp.types import CameraModel, Frame, PoseEstimate


def pose_message(seq: int, estimate: PoseEstimate, reset_counter: int, processing_ms: float, visual_age_s: float | None = None, navigation=None) -> Pose:
    """The wire form of an estimate: camera-to-world t and (qw, qx, qy, qz), the navigation flags,
    and, from the ``navigation`` stage when there is one, its GPS state and (georeferenced) the
    latitude, longitude and altitude."""
    qx, qy, qz, qw = quat_xyzw_from_matrices(estimate.T_world_cam[None, :3, :3])[0]
    covariance = None if estimate.covariance is None else [float(v) for v in np.asarray(estimate.covariance).reshape(-1)]
    geodetic = navigation.geodetic(estimate.T_world_cam[:3, 3]) if navigation is not None and estimate.georeferenced else None
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
        metric=estimate.metric,
        scale_known=estimate.scale_known,
        georeferenced=estimate.georeferenced,
        gps_trusted=estimate.gps_trusted,
        gps="none" if navigation is None else navigation.gps_state,
        velocity=None if estimate.velocity is None else [float(v) for v in estimate.velocity],
        velocity_covariance=None if estimate.velocity_covariance is None else [float(v) for v in estimate.velocity_covariance.reshape(-1)],
        latitude_deg=None if geodetic is None else geodetic[0],
        longitude_deg=None if geodetic is None else geodetic[1],
        altitude_m=None if geodetic is None else geodetic[2],
        visual_age_s=visual_age_s,
    )


def not_yet_message(seq: int, timestamp: float, gps: str) -> Pose:
    """The answer before the estimator has answered anything: no pose yet."""
    return Pose(seq=seq, timestamp=timestamp, t=[0.0, 0.0, 0.0], q=[1.0, 0.0, 0.0, 0.0], state="NOT_INITIALIZED", gps=gps)


def pose_matrix(pose: Pose) -> np.ndarray:
    """T_world_cam (4x4) of a wire pose."""
    qw, qx, qy, qz = pose.q
    return poses_from_xyz_quat(np.array([pose.t]), np.array([[qx, qy, qz, qw]]))[0]


class PoseSender(Sink):
    """Sends each answer (or why a frame had none) back over the process's pipe (``after_vision``:
    the pipeline's own answers)."""

    def __init__(self, send, estimator, navigation=None):
        self.send = send
        self.estimator = estimator
        self.navigation = navigation

    def on_estimate(self, frame: Frame, estimate: PoseEstimate, elapsed_ms: float) -> None:
        reset_counter = estimator_jumps(self.estimator) + (self.navigation.world_changes if self.navigation is not None else 0)
        self.send(("pose", pose_message(frame.index, estimate, reset_counter, elapsed_ms, 0.0, self.navigation)))

    def on_skip(self, frame: Frame | None, reason: str) -> None:
        self.send(("error", ("corrupt_image", reason, None if frame is None else frame.index)))


# The link's thread needs the GIL for a few short steps per frame (unpickle, decode, predict,
# send) while the vision thread holds it in SLAM's Python code; at Python's default 5 ms switch
# interval each step can wait 5 ms (measured: p50 60 ms frame-sent to answer on a loaded 2-core
# machine). At 1 ms the answer waits less; SLAM loses a little to the extra switches.
LINK_SWITCH_INTERVAL_S = 0.001

# A sensor that keeps misbehaving (an IMU at an irregular rate, a GPS without lock for minutes)
# would flood the operator's event log: each notice code is told at most once per this many
# seconds, with the count of those held back. GPS trust events are rare and always told.
NOTICE_REPEAT_S = 5.0
ALWAYS_TOLD = ("spoofing_alarm", "gps_lost", "gps_back", "trust_restored", "navigation_started", "georeferenced")


class NavigationReports:
    """What the navigation stage tells the operator: its new notices (repeats of a code held back
    for ``NOTICE_REPEAT_S``), and its state (filter status, GPS state, alignment progress) when it
    changed, at most once a second."""

    def __init__(self, send, live: LivePipeline, stage):
        self.send, self.live, self.stage = send, live, stage
        self._told = 0
        self._last_state: dict | None = None
        self._state_at = -math.inf
        self._code_told_at: dict[str, float] = {}
        self._held: dict[str, int] = {}

    def tell(self, now: float) -> None:
        with self.live.locked():
            notices = self.stage.notices[self._told :]
            self._told += len(notices)
            state = navigation_state(self.stage) if now - self._state_at >= 1.0 else None
        for notice in notices:
            if notice.code not in ALWAYS_TOLD and now - self._code_told_at.get(notice.code, -math.inf) < NOTICE_REPEAT_S:
                self._held[notice.code] = self._held.get(notice.code, 0) + 1
                continue
            held = self._held.pop(notice.code, 0)
            self._code_told_at[notice.code] = now
            self.send(("notice", (notice.level, notice.code, notice.text + (f" ({held} more like it before)" if held else ""))))
        if state is not None and state != self._last_state:
            self._last_state, self._state_at = state, now
            self.send(("navigation", state))


def navigation_state(stage) -> dict:
    """The stage's state for the operator (plain data)."""
    progress = stage.alignment_progress
    return {
        "status": stage.status,
        "running": stage.filter is not None,
        "gps": stage.gps_state,
        "alignment": None if progress is None else asdict(progress),
        "sensors": sorted(stage.sensors_used),
    }


def make_session_estimator(camera: CameraModel, settings, T_body_cam: list[float] | None):
    """A session's configured estimator: the same ``make_estimator`` as ``evp run``, with the
    camera's extrinsic the mobile station sent (the EKF-SLAM's camera on the robot)."""
    from evp.run_setup import make_estimator

    return make_estimator(camera, settings, T_body_cam=None if T_body_cam is None else np.asarray(T_body_cam, float).reshape(4, 4))


class SessionEstimatorServer(EstimatorServer):
    """A session's estimator built where it runs: in the vision process, or as an actor on a
    cluster's worker (``station.cluster``)."""

    def __init__(self, camera: CameraModel, settings_json: str, T_body_cam: list[float] | None = None):
        from evp.config import Settings

        settings = Settings.model_validate_json(settings_json)
        priority = ThreadPriority(settings.station.vision_nice) if settings.station.vision_nice else None
        if priority is not None:
            priority.lower()  # before the estimator starts its own threads (local mapping): they inherit it
        super().__init__(make_session_estimator(camera, settings, T_body_cam), priority)


def vision_main(connection, camera: CameraModel, settings_json: str, T_body_cam: list[float] | None = None) -> None:
    """The vision process (``EstimatorProcess``'s partner, ``station.vision_process``): the
    session's estimator, fed by the estimator process's :class:`RemoteEstimator`."""
    serve_estimator(connection, SessionEstimatorServer(camera, settings_json, T_body_cam))


def worker_main(connection, camera: CameraModel, settings_json: str, T_body_cam: list[float] | None = None, answers: str = "at_once", vision=None) -> None:
    """The estimator process (``EstimatorProcess``'s target): the one pipeline over the wire's
    frames and telemetry, with the navigation stage when the mobile station gave its camera's
    extrinsic to the IMU (``T_body_cam``) and the estimator is SLAM; see
    :mod:`evp.runtime.live_pipeline` for how ``answers`` at once and vision share it. With
    ``vision`` (the pipe to :func:`vision_main`'s process) the estimator runs there; with
    ``station.cluster`` on a worker of that Dask cluster."""
    from evp.config import Settings
    from evp.fusion.navigation_stage import NavigationStage
    from evp.run_setup import saved_map_georeference

    settings = Settings.model_validate_json(settings_json)
    if settings.station.cluster:
        estimator = ClusterEstimator(settings.station.cluster, SessionEstimatorServer, camera, settings_json, T_body_cam)
    elif vision is not None:
        estimator = RemoteEstimator(vision)
    else:
        estimator = make_session_estimator(camera, settings, T_body_cam)
    sys.setswitchinterval(LINK_SWITCH_INTERVAL_S)
    lock = threading.Lock()

    def send(item) -> None:
        with lock:
            connection.send(item)

    stage = None
    if T_body_cam is not None and settings.navigation.enabled and settings.estimator in ("slam", "auto"):
        matrix = np.asarray(T_body_cam, float).reshape(4, 4)
        georeference = saved_map_georeference(settings) if getattr(estimator, "in_saved_map", False) else None
        stage = NavigationStage(matrix, settings.navigation, lambda: estimator.reset_counter, settings.gps_monitor, map_georeference=georeference)
    at_once = answers != "after_vision"
    sinks = [] if at_once else [PoseSender(send, estimator, stage)]
    live = LivePipeline(Pipeline(estimator, sinks, [stage] if stage is not None else []), at_once, settings.station.vision_wait_s)
    reports = NavigationReports(send, live, stage) if stage is not None else None
    send(("ready", None))
    try:
        _serve(connection, live, send, reports, stage)
    finally:
        live.close()
    if reports is not None:
        reports.tell(math.inf)
    try:
        send(("finished", None))
    except (BrokenPipeError, OSError):  # the station is gone
        pass


def _serve(connection, live: LivePipeline, send, reports: NavigationReports | None, stage) -> None:
    """The link's thread: telemetry to the stages, each frame answered (at once) and offered to
    vision, until the station sends None or goes away, or vision fails (the process then ends
    with the error, and the session's supervisor starts a new estimator)."""
    while True:
        if live.failed is not None:
            raise RuntimeError(f"vision failed: {live.failed}") from live.failed
        try:
            item = connection.recv()
        except EOFError:  # the station is gone
            return
        if item is None:
            return
        if isinstance(item, tuple):  # ("telemetry", [record, ...])
            for record in item[1]:
                live.telemetry(record)
        else:
            start = time.perf_counter()
            try:  # decoded before it is answered: an image that does not decode gets its error, not a pose
                frame = Frame(item.timestamp, image_pixels(item), index=item.seq, source="stream")
            except ProtocolError as exc:
                send(("error", (exc.code, exc.message, item.seq)))
                continue
            answer = live.frame(frame)
            if answer is not None:
                send(("pose", answer_message(answer, stage, live, (time.perf_counter() - start) * 1000.0)))
        if reports is not None:
            reports.tell(time.monotonic())


def answer_message(answer: LiveAnswer, stage, live: LivePipeline, processing_ms: float) -> Pose:
    if stage is None:
        if answer.estimate is None:
            return not_yet_message(answer.seq, answer.timestamp, "none")
        return pose_message(answer.seq, answer.estimate, answer.reset_counter, processing_ms, answer.visual_age_s)
    with live.locked():
        if answer.estimate is None:
            return not_yet_message(answer.seq, answer.timestamp, stage.gps_state)
        return pose_message(answer.seq, answer.estimate, answer.reset_counter, processing_ms, answer.visual_age_s, stage)
