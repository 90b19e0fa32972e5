"""The station running ``estimator: ekf-slam`` for a session (seed 001 live): a short render of the
robot room streamed as ``evp stream --encoder-ticks`` sends it (frames, and the wheels as encoder
counts), answered with metric poses that follow the rendered path."""

from __future__ import annotations

import asyncio
import time

import numpy as np
import pytest

from evp.config import Settings
from evp.eval.association import associate
from evp.eval.metrics import Alignment, align_trajectory, ape_translation
from evp.io.registry import open_dataset
from evp.mobile.sources import open_source, telemetry_message
from evp.sim.generate import generate
from evp.sim.scenarios import SimOptions
from evp.station.auth import DEV
from evp.station.base_station import Station
from evp.station.estimation import pose_matrix
from evp.station.protocol import PROTOCOL_VERSION, Config, Hello, encode, encode_image
from evp.types import EncoderCounts, Trajectory, WheelOdometry
from tests.station.test_durability import Phone

FRAMES = 24


@pytest.fixture(scope="module")
def robot_room(tmp_path_factory):
    out = tmp_path_factory.mktemp("robot")
    generate("wheel-robot-room", SimOptions(seed=4, duration_s=4.0, fps=8.0), out, workers=1)
    return open_dataset(out)


def test_the_station_runs_ekf_slam_on_a_streamed_robot(tmp_path, robot_room):
    dataset = robot_room
    settings = Settings.model_validate({"estimator": "ekf-slam"})
    source = open_source(str(dataset.root), max_frames=FRAMES, encoder_robot=settings.robot)  # evp stream --encoder-ticks
    items = list(source.items)
    assert not any(isinstance(item, WheelOdometry) for item in items) and any(isinstance(item, EncoderCounts) for item in items)

    async def scenario() -> Phone:
        station = Station(tmp_path / "data", settings)
        session, _ = station.open_session(Hello(protocol=PROTOCOL_VERSION, device="robot"), DEV)
        phone = Phone(session)
        try:
            extrinsic = [float(v) for v in dataset.T_body_cam.reshape(-1)]
            session.on_text(encode(Config(camera=dataset.camera, T_body_cam=extrinsic, answers="after_vision")), time.time())
            await phone.until(lambda m: m.type == "status" and m.state == "running", what="the EKF-SLAM ready")
            for item in items:
                if hasattr(item, "image"):
                    session.on_binary(encode_image(item.image, item.index, item.timestamp, "png").pack(), time.time())
                    await phone.until(lambda m, seq=item.index: m.type in ("pose", "error", "dropped") and getattr(m, "seq", None) == seq, what="the answer")
                elif isinstance(item, EncoderCounts):  # the robot's wheels (its IMU and WiFi are not needed here)
                    session.on_text(encode(telemetry_message(item)), time.time())
        finally:
            await station.stop()
        return phone

    phone = asyncio.run(scenario())
    poses = [m for m in phone.messages if m.type == "pose"]
    assert len(poses) == FRAMES and all(p.metric and p.state == "OK" for p in poses)
    estimate = Trajectory.from_poses(np.array([pose_matrix(p) for p in poses]), np.array([p.timestamp for p in poses]))
    ref, est = associate(dataset.ground_truth, estimate, 0.01)
    assert len(ref) == FRAMES
    travelled = np.linalg.norm(ref.positions[-1] - ref.positions[0])
    assert travelled > 0.25  # after its 2 s standstill: metric poses, no scale alignment
    assert abs(np.linalg.norm(est.positions[-1] - est.positions[0]) - travelled) < 0.02
    assert ape_translation(ref, align_trajectory(ref, est, Alignment.SE3)[0]).max() < 0.03
