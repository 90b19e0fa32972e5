"""The bundled sample streamed by ``evp stream`` to ``evp serve`` over loopback (TLS), with MAVLink out.

Checks: a pose for >= 95 % of frames; the live trajectory equals ``evp run``'s on the same data;
the database and the MCAP recording hold every frame and message; ``evp replay`` reproduces the
live poses; the MAVLink listener decodes ODOMETRY (only) at >= 30 Hz.
"""

from __future__ import annotations

import os
import subprocess
import sys
import threading
import time
from collections import Counter

import numpy as np

from evp.config import Settings
from evp.io.registry import open_dataset
from evp.pipeline import run_dataset
from evp.run_setup import make_estimator
from evp.station.recording import has_summary
from evp.station.store import SessionStore
from tests.conftest import SAMPLE
from tests.station.conftest import OperatorFeed, free_port, indexed_messages, run_stream, running_station, station_database

os.environ.setdefault("MAVLINK20", "1")


class MavlinkListener(threading.Thread):
    def __init__(self, port: int):
        super().__init__(daemon=True)
        from pymavlink import mavutil

        self.connection = mavutil.mavlink_connection(f"udpin:127.0.0.1:{port}", dialect="common")
        self.messages: list[tuple[float, object]] = []
        self.running = True

    def run(self) -> None:
        while self.running:
            message = self.connection.recv_match(type=["ODOMETRY", "VISION_POSITION_ESTIMATE", "HEARTBEAT"], blocking=True, timeout=0.2)
            if message is not None:
                self.messages.append((time.monotonic(), message))


def _offline_live_trajectory() -> dict[float, np.ndarray]:
    dataset = open_dataset(SAMPLE)
    result = run_dataset(dataset, make_estimator(dataset.camera, Settings(), dataset))
    trajectory = result.trajectory()
    return {round(float(t), 6): p for t, p in zip(trajectory.timestamps, trajectory.positions)}


def test_sample_streamed_to_the_station_matches_evp_run(tmp_path, station_data):
    mavlink_port = free_port(kind=2)  # SOCK_DGRAM
    listener = MavlinkListener(mavlink_port)
    listener.start()
    with running_station(station_data, "--mavlink", f"udpout:127.0.0.1:{mavlink_port}") as station, OperatorFeed(station) as feed:
        cafile = str(station_data / "tls" / "cert.pem")
        summary = run_stream(str(SAMPLE), "--url", station.url, "--cafile", cafile, "--quiet", "--out", str(tmp_path / "stream"))
        feed.event("ended", summary["session_id"])
    listener.running = False
    listener.join()

    frames = 87
    assert summary["frames_sent"] == frames and summary["errors"] == 0
    assert summary["poses_received"] >= 0.95 * frames
    assert summary["session_id"] and summary["latency_ms_p50"] > 0

    streamed = np.loadtxt(tmp_path / "stream" / "poses.tum")
    offline = _offline_live_trajectory()
    assert len(streamed) == len(offline) >= 0.9 * frames
    differences = [np.linalg.norm(row[1:4] - offline[round(row[0], 6)]) for row in streamed]
    assert max(differences) < 1e-9

    store = SessionStore(station_database(station_data))
    try:
        session = store.session(summary["session_id"])
        assert session["status"] == "ended"
        assert (session["frames_received"], session["frames_estimated"], session["frames_dropped"]) == (frames, frames, 0)
        assert sorted(r["seq"] for r in store.rows("frames", session["id"])) == list(range(frames))
        assert len(store.rows("poses", session["id"])) == frames
        codes = [e["code"] for e in store.rows("events", session["id"])]
        assert codes[0] == "connected" and "estimator_ready" in codes and codes[-1] == "ended"
        assert has_summary(session["mcap_path"])
        topics = Counter(topic for topic, _, _ in indexed_messages(session["mcap_path"]))
        assert topics["/camera/image/compressed"] == frames and topics["/evp/pose"] == frames and topics["/camera/camera_info"] == 1
        assert topics["/tf"] == frames  # the camera's pose, where Foxglove's 3-D panel places it

        replay = subprocess.run(
            [sys.executable, "-m", "evp.cli", "replay", summary["session_id"], "--data", str(station_data), "--db", station_database(station_data), "--out", str(tmp_path / "replay")],
            capture_output=True, text=True, timeout=300,
        )  # fmt: skip
        assert replay.returncode == 0, replay.stderr
        assert '"max_position_difference": 0.0' in replay.stdout and f'"matched": {frames}' in replay.stdout
    finally:
        store.close()

    odometry = [(t, m) for t, m in listener.messages if m.get_type() == "ODOMETRY"]
    vision = [m for _, m in listener.messages if m.get_type() == "VISION_POSITION_ESTIMATE"]
    assert len(odometry) > 30 and not vision  # one message type (the ardupilot profile): no pose fused twice
    assert all(m.frame_id == 20 and m.child_frame_id == 12 and 0 <= m.quality <= 100 for _, m in odometry)  # LOCAL_FRD, BODY_FRD
    assert any(m.get_type() == "HEARTBEAT" for _, m in listener.messages)
    times = np.array([t for t, _ in odometry])
    gaps = np.diff(times)
    rate = 1.0 / np.median(gaps)
    assert rate >= 30.0, f"ODOMETRY at {rate:.1f} Hz"
