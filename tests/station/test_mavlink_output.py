"""MAVLink output: camera-to-body/NED conversion for each mount, and the messages a listener decodes."""

from __future__ import annotations

import math
import os
import time

import numpy as np
import pytest

from evp.config import MavlinkSettings
from evp.geometry.transforms import se3
from evp.station.mavlink_out import MavlinkOutput, body_pose_ned, euler_frd, mount_transform
from tests.station.conftest import free_port

os.environ.setdefault("MAVLINK20", "1")


def _rot_z(angle: float) -> np.ndarray:
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def test_down_camera_moving_towards_the_image_top_is_the_vehicle_flying_forward():
    T_body_cam = mount_transform(MavlinkSettings())
    # the camera moved 2 m along its -y axis (towards the top of the image) and sank 1 m along +z
    T_world_cam = se3(np.eye(3), np.array([0.0, -2.0, 1.0]))
    T = body_pose_ned(T_world_cam, T_body_cam)
    assert np.allclose(T[:3, 3], [2.0, 0.0, 1.0])  # north 2 m, down 1 m
    assert np.allclose(T[:3, :3], np.eye(3))


def test_camera_yaw_becomes_vehicle_yaw_for_both_mounts():
    for mount, optical_axis_rotation in (("down", _rot_z(0.3)), ("forward", None)):
        T_body_cam = mount_transform(MavlinkSettings(mount=mount))
        if mount == "forward":  # a forward camera turns right by rotating about its own -y axis (image up)
            c, s = math.cos(0.3), math.sin(0.3)
            optical_axis_rotation = np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])
        roll, pitch, yaw = euler_frd(body_pose_ned(se3(optical_axis_rotation, np.zeros(3)), T_body_cam)[:3, :3])
        assert abs(roll) < 1e-9 and abs(pitch) < 1e-9
        assert yaw == pytest.approx(0.3, abs=1e-9), mount


def test_listener_decodes_odometry_and_vision_position_at_the_configured_rate():
    from pymavlink import mavutil

    port = free_port(kind=2)
    listener = mavutil.mavlink_connection(f"udpin:127.0.0.1:{port}", dialect="common")
    output = MavlinkOutput(f"udpout:127.0.0.1:{port}", MavlinkSettings(rate_hz=50.0, max_extrapolation_s=0.5))
    received = []
    try:
        start = time.monotonic()
        for k in range(30):  # 1 s of poses at 30 Hz: the camera drifts towards the image top at 0.9 m/s
            output.update(se3(np.eye(3), np.array([0.0, -0.03 * k, 0.0])), 100.0 + k / 30.0, "OK", 70, reset_counter=3)
            while time.monotonic() < start + (k + 1) / 30.0:
                message = listener.recv_match(type=["ODOMETRY", "VISION_POSITION_ESTIMATE"], blocking=True, timeout=0.01)
                if message is not None:
                    received.append((time.monotonic(), message))
        output.update(np.eye(4), 102.0, "LOST", 0, reset_counter=3)

        def quiet(seconds: float) -> bool:
            """No pose message for ``seconds``; a message ends the wait at once."""
            return listener.recv_match(type=["ODOMETRY", "VISION_POSITION_ESTIMATE"], blocking=True, timeout=seconds) is None

        # what was sent before the loss (a tick that read the pose just before it included) is still
        # arriving; at 50 Hz a pause of 5 ticks means the stream stopped, and it must stop within 10
        assert any(quiet(0.1) for _ in range(10)), "the pose stream went on after the loss"
        assert quiet(0.3)  # silence while lost
    finally:
        output.close()
        listener.close()
    odometry = [m for _, m in received if m.get_type() == "ODOMETRY"]
    vision = [m for _, m in received if m.get_type() == "VISION_POSITION_ESTIMATE"]
    span = received[-1][0] - received[0][0]
    assert len(odometry) / span >= 40.0 and len(vision) == pytest.approx(len(odometry), abs=2)
    last = odometry[-1]
    assert (last.frame_id, last.child_frame_id, last.quality, last.reset_counter) == (1, 12, 70, 3)
    assert last.x == pytest.approx(0.87, abs=0.06) and abs(last.y) < 1e-6 and abs(last.z) < 1e-6  # north, extrapolated < 1 frame
    assert last.vx == pytest.approx(0.9, abs=0.01) and last.q[0] == pytest.approx(1.0)
    assert math.isnan(last.pose_covariance[0])
    assert all(b.time_usec >= a.time_usec for a, b in zip(odometry, odometry[1:]))
