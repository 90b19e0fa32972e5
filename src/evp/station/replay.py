"""``evp replay SESSION``: run a recorded session through the estimator again, offline.

Feeds the recorded image bytes, with the settings and camera the station used, to a fresh
estimator that restarts where the live one did, and by default only the frames the live
estimator saw (not those dropped as stale), so the result equals the live trajectory.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass
from itertools import chain, groupby
from pathlib import Path

import numpy as np

from evp.errors import DataError, UsageError
from evp.io.trajectory import tum_text
from evp.pipeline import Pipeline, Sink
from evp.station.estimation import pose_message
from evp.station.protocol import ENCODING_IDS, ImageMessage, Pose, ProtocolError, image_pixels
from evp.station.recording import RAW_ROS_ENCODING, TOPIC_CAMERA_INFO, TOPIC_IMAGE_COMPRESSED, TOPIC_IMAGE_RAW, decoded_messages
from evp.station.store import SessionStore
from evp.types import Frame, PoseEstimate, TrackingState, Trajectory

ROS_TO_RAW = {ros: ours for ours, ros in RAW_ROS_ENCODING.items()}


@dataclass
class RecordedFrame:
    received_at_ns: int
    message: ImageMessage
    estimated_live: bool


def _frame_rows(store: SessionStore, session_id: str) -> dict[int, dict]:
    return {int(round(row["received_at"] * 1e9)): row for row in store.rows("frames", session_id)}


def recorded_frames(store: SessionStore, session_id: str, mcap_path: Path) -> Iterator[tuple[str, float, object]]:
    """('camera', t, CameraInfo) and ('frame', t, RecordedFrame) in the order the station got them
    (t: station time in seconds)."""
    rows = _frame_rows(store, session_id)
    for topic, log_time_ns, msg in decoded_messages(mcap_path, {TOPIC_IMAGE_COMPRESSED, TOPIC_IMAGE_RAW, TOPIC_CAMERA_INFO}):
        log_time = log_time_ns * 1e-9
        if topic == TOPIC_CAMERA_INFO:
            yield "camera", log_time, msg
            continue
        row = rows.get(log_time_ns)
        if row is None:
            continue  # an image the station refused before numbering it (bad header)
        encoding = msg.format if topic == TOPIC_IMAGE_COMPRESSED else ROS_TO_RAW.get(msg.encoding, "")
        if encoding not in ENCODING_IDS:
            continue
        message = ImageMessage(row["seq"], row["timestamp"], encoding, row["width"], row["height"], np.asarray(msg.data, dtype=np.uint8).tobytes())
        yield "frame", log_time, RecordedFrame(log_time_ns, message, bool(row["estimated"]))


class _PoseRecorder(Sink):
    """Keeps each answer in its wire form, as the station sent it live."""

    def __init__(self, estimator, poses: list[Pose]):
        self.estimator = estimator
        self.poses = poses

    def on_estimate(self, frame: Frame, estimate: PoseEstimate, elapsed_ms: float) -> None:
        self.poses.append(pose_message(frame.index, estimate, self.estimator.reset_counter, 0.0))


def _decoded(frames: Iterable[RecordedFrame]) -> Iterator[Frame]:
    """The recorded images as frames; one that does not decode is left out, as live."""
    for item in frames:
        try:
            image = image_pixels(item.message)
        except ProtocolError:
            continue
        yield Frame(item.message.timestamp, image, index=item.message.seq, source="stream")


def _frames_by_start(
    store: SessionStore, session_id: str, mcap_path: Path, starts: list, all_frames: bool, progress: Callable[[int], None] | None
) -> Iterator[tuple[tuple, RecordedFrame]]:
    """((start number, camera, settings) of the estimator start in force, frame) for each frame to replay; frames
    before the first start, or before any camera, had no estimator live and are left out."""
    from evp.io.ros_messages import msg_to_camera

    camera = None
    current = None
    start_index = -1
    for kind, log_time, item in recorded_frames(store, session_id, mcap_path):
        if kind == "camera":
            camera = msg_to_camera(item, mcap_path)
            continue
        while start_index + 1 < len(starts) and starts[start_index + 1][0] <= log_time:
            start_index += 1
            current = (start_index, camera, starts[start_index][1]) if camera is not None else None
        if progress:
            progress(1)
        if current is not None and (item.estimated_live or all_frames):
            yield current, item


def replay(store: SessionStore, session_id: str, all_frames: bool = False, progress: Callable[[int], None] | None = None) -> list[Pose]:
    """Poses for the recorded frames, from estimators (re)started where the live ones were: one
    pipeline per estimator start, fed the frames recorded until the next start."""
    from evp.config import Settings
    from evp.run_setup import make_estimator

    row = store.session(session_id)
    if row is None:
        raise UsageError(f"no session {session_id!r} in {store.url}")
    mcap_path = Path(row["mcap_path"] or "")
    if not mcap_path.is_file():
        raise DataError(f"session {session_id}: recording {mcap_path} is missing")
    starts = [(s["t"], Settings.model_validate_json(s["data_json"])) for s in store.rows("settings", session_id) if s["source"] == "server"]
    if not starts:
        raise DataError(f"session {session_id}: the estimator never started live; nothing to replay")
    poses: list[Pose] = []
    for _, run in groupby(_frames_by_start(store, session_id, mcap_path, starts, all_frames, progress), key=lambda pair: pair[0][0]):
        (_, camera, settings), first = next(run)
        estimator = make_estimator(camera, settings)
        rest = (item for _, item in run)  # noqa: B031 - the group is read once, after its first item
        Pipeline(estimator, [_PoseRecorder(estimator, poses)]).run(_decoded(chain([first], rest)))
    return poses


def compare_with_live(store: SessionStore, session_id: str, poses: list[Pose]) -> dict:
    """How far the replayed poses are from those sent live (same frames)."""
    live = {(r["seq"], r["timestamp"]): r for r in store.rows("poses", session_id)}
    differences = []
    same_state = 0
    for pose in poses:
        row = live.get((pose.seq, pose.timestamp))
        if row is None:
            continue
        same_state += row["state"] == pose.state
        differences.append(float(np.linalg.norm(np.array(pose.t) - [row["tx"], row["ty"], row["tz"]])))
    return {
        "session_id": session_id,
        "poses_replayed": len(poses),
        "poses_live": len(live),
        "matched": len(differences),
        "same_state": same_state,
        "max_position_difference": max(differences) if differences else None,
        "median_position_difference": float(np.median(differences)) if differences else None,
    }


def live_poses(store: SessionStore, session_id: str) -> list[Pose]:
    """The poses the station sent during a session, from the database."""
    return [
        Pose(
            seq=r["seq"],
            timestamp=r["timestamp"],
            t=[r["tx"], r["ty"], r["tz"]],
            q=[r["qw"], r["qx"], r["qy"], r["qz"]],
            state=r["state"],
            quality=r["quality"],
            reset_counter=r["reset_counter"],
        )
        for r in store.rows("poses", session_id)
    ]


def tracked_trajectory(poses: list[Pose]) -> Trajectory:
    """The tracked wire poses as a trajectory (the wire's (qw, qx, qy, qz) turned to x, y, z, w)."""
    tracked = [p for p in poses if TrackingState(p.state).tracked]
    return Trajectory(
        np.array([p.t for p in tracked], float).reshape(-1, 3),
        np.array([[*p.q[1:], p.q[0]] for p in tracked], float).reshape(-1, 4),
        np.array([p.timestamp for p in tracked], float),
    )


def write_replay(out: Path, store: SessionStore, session_id: str, poses: list[Pose]) -> dict:
    out.mkdir(parents=True, exist_ok=True)
    (out / "trajectory.tum").write_text(tum_text(tracked_trajectory(poses)))
    (out / "trajectory_live.tum").write_text(tum_text(tracked_trajectory(live_poses(store, session_id))))
    comparison = compare_with_live(store, session_id, poses)
    (out / "comparison.json").write_text(json.dumps(comparison, indent=2))
    return comparison
