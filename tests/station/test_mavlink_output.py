"""MAVLink output: camera-to-body/NED conversion for each mount, and the messages a listener decodes."""

from __future__ import annotations

import math
import os
import time

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from evp.config import MavlinkSettings
from evp.geometry.transforms import se3
from evp.station.mavlink_out import MavlinkOutput, body_pose_ned, euler_frd, mount_transform
from evp.station.protocol import Pose
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


def _pose(k: int, **fields) -> Pose:
    """A visual-map answer at 30 Hz: the camera drifts towards the image top at 0.9 m/s."""
    values = {"seq": k, "timestamp": 100.0 + k / 30.0, "t": [0.0, -0.03 * k, 0.0], "q": [1.0, 0.0, 0.0, 0.0], "state": "OK", "quality": 70}
    return Pose(**{**values, **fields})


def _metric_pose(k: int, georeferenced: bool, reset_counter: int = 0) -> Pose:
    """A navigation-filter answer: a down camera over ENU flying east at 3 m/s, 20 m up, image top
    to the east (the body's nose east: heading 90 degrees)."""
    R_world_cam = np.array([[0.0, -1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])  # x south... z down
    qx, qy, qz, qw = Rotation.from_matrix(R_world_cam).as_quat()
    covariance = np.diag([0.04, 0.09, 0.25, 1e-4, 1e-4, 4e-4])
    return Pose(
        seq=k, timestamp=100.0 + k / 30.0, t=[3.0 * k / 30.0, 0.0, 20.0], q=[qw, qx, qy, qz], state="OK", quality=80,
        reset_counter=reset_counter, covariance=list(covariance.reshape(-1)), metric=True, scale_known=True, georeferenced=georeferenced,
        gps_trusted=georeferenced, gps="trusted" if georeferenced else "aligning", velocity=[3.0, 0.0, 0.0],
        velocity_covariance=list(np.diag([0.01, 0.01, 0.04]).reshape(-1)),
        latitude_deg=43.7 if georeferenced else None, longitude_deg=10.4 if georeferenced else None, altitude_m=24.0 if georeferenced else None,
    )  # fmt: skip


class _Listener:
    """A pymavlink listener on a free loopback UDP port."""

    def __init__(self):
        from pymavlink import mavutil

        self.port = free_port(kind=2)
        self.connection = mavutil.mavlink_connection(f"udpin:127.0.0.1:{self.port}", dialect="common")
        self.received: list[tuple[float, object]] = []

    def drain(self, until: float) -> None:
        while time.monotonic() < until:
            message = self.connection.recv_match(blocking=True, timeout=0.01)
            if message is not None and message.get_type() != "BAD_DATA":
                self.received.append((time.monotonic(), message))

    def of_type(self, kind: str) -> list:
        return [m for _, m in self.received if m.get_type() == kind]

    def close(self) -> None:
        self.connection.close()


def _stream(output: MavlinkOutput, listener: _Listener, poses, resets) -> None:
    """Each pose at 30 Hz with its reset counter, listening all along."""
    start = time.monotonic()
    for k, (pose, reset) in enumerate(zip(poses, resets)):
        output.update(pose, reset)
        listener.drain(start + (k + 1) / 30.0)


def test_visual_map_answers_stream_at_the_configured_rate_and_stop_when_lost():
    listener = _Listener()
    output = MavlinkOutput(f"udpout:127.0.0.1:{listener.port}", MavlinkSettings(rate_hz=50.0, max_extrapolation_s=0.5))
    try:
        _stream(output, listener, [_pose(k) for k in range(30)], [3] * 30)
        output.update(_pose(60, state="LOST", quality=0), 3)
        listener.received.clear()
        listener.drain(time.monotonic() + 0.1)  # what was already on its way
        listener.received.clear()
        listener.drain(time.monotonic() + 0.3)
        assert not listener.of_type("ODOMETRY"), "the pose stream went on after the loss"
    finally:
        output.close()
        listener.close()


def test_each_profile_sends_one_message_type_with_its_frames_covariance_and_reset_counter():
    from pymavlink.dialects.v20 import common as mavlink

    expected = {  # profile: (frame before the heading is known, after)
        "ardupilot": (mavlink.MAV_FRAME_LOCAL_FRD, mavlink.MAV_FRAME_LOCAL_FRD),
        "px4": (mavlink.MAV_FRAME_LOCAL_FRD, mavlink.MAV_FRAME_LOCAL_NED),
    }
    for name, (before, after) in expected.items():
        listener = _Listener()
        output = MavlinkOutput(f"udpout:127.0.0.1:{listener.port}", MavlinkSettings(profile=name, rate_hz=50.0, max_extrapolation_s=0.5))
        try:
            # 0.5 s aligning, then georeferenced; the answers' reset counter steps with a map reset
            # at frame 5 and a loop correction at frame 10 (the station's counters, passed on)
            poses = [_metric_pose(k, georeferenced=k >= 15) for k in range(30)]
            resets = [0] * 5 + [1] * 5 + [2] * 20
            _stream(output, listener, poses, resets)
        finally:
            output.close()
            listener.close()
        types = {m.get_type() for _, m in listener.received} - {"HEARTBEAT"}
        assert types == {"ODOMETRY"}, name  # one message type: nothing fused twice
        odometry = listener.of_type("ODOMETRY")
        span = listener.received[-1][0] - listener.received[0][0]
        assert len(odometry) / span >= 40.0, name
        assert {m.frame_id for m in odometry if m.reset_counter < 2} == {before}, name
        assert odometry[-1].frame_id == after and odometry[-1].child_frame_id == mavlink.MAV_FRAME_BODY_FRD, name
        assert sorted({m.reset_counter for m in odometry}) == [0, 1, 2], name
        last = odometry[-1]
        assert all(math.isfinite(v) for v in last.pose_covariance) and last.pose_covariance[0] == pytest.approx(0.09)  # north = ENU y
        assert last.pose_covariance[20] == pytest.approx(4e-4) and last.velocity_covariance[0] == pytest.approx(0.01, rel=1e-5)
        assert last.quality == 80 and last.estimator_type == mavlink.MAV_ESTIMATOR_TYPE_VIO
        # NED: flying east 20 m up; body FRD: forward at 3 m/s
        assert last.y == pytest.approx(3.0 * 29 / 30, abs=0.15) and last.z == pytest.approx(-20.0, abs=1e-4)
        assert last.vx == pytest.approx(3.0, abs=1e-4) and abs(last.vy) < 1e-4
        roll, pitch, yaw = euler_frd(Rotation.from_quat([*last.q[1:], last.q[0]]).as_matrix())
        assert yaw == pytest.approx(math.pi / 2, abs=1e-5) and abs(roll) < 1e-6 and abs(pitch) < 1e-6
        assert all(b.time_usec >= a.time_usec for a, b in zip(odometry, odometry[1:]))


def test_gps_input_only_while_georeferenced():
    listener = _Listener()
    output = MavlinkOutput(f"udpout:127.0.0.1:{listener.port}", MavlinkSettings(gps_input=True, max_extrapolation_s=0.5))
    try:
        _stream(output, listener, [_metric_pose(k, georeferenced=False) for k in range(15)], [0] * 15)
        assert not listener.of_type("GPS_INPUT")
        _stream(output, listener, [_metric_pose(k, georeferenced=True) for k in range(15, 45)], [1] * 30)
    finally:
        output.close()
        listener.close()
    gps = listener.of_type("GPS_INPUT")
    assert 3 <= len(gps) <= 7  # 5 Hz over 1 s
    assert gps[-1].lat == 437000000 and gps[-1].lon == 104000000 and gps[-1].fix_type == 3
    assert gps[-1].horiz_accuracy == pytest.approx(math.sqrt(0.065), rel=1e-4) and gps[-1].ve == pytest.approx(3.0)


def test_each_vehicle_gets_its_own_route_and_its_gps_alarms_as_statustext():
    from evp.station.mavlink_routes import MavlinkRoutes

    default, own = _Listener(), _Listener()
    problems = []
    settings = MavlinkSettings(system_id=7, vehicles={"drone-b": f"udpout:127.0.0.1:{own.port}"})
    routes = MavlinkRoutes(f"udpout:127.0.0.1:{default.port}", settings, lambda session, text: problems.append((session, text)))
    try:
        a, b, c = routes.output("s-a", "drone-a"), routes.output("s-b", "drone-b"), routes.output("s-c", "drone-c")
        assert (a.url, a.system_id) == (routes.default_url, 7) and (c.url, c.system_id) == (routes.default_url, 8)
        assert b.url.endswith(str(own.port))
        for k in range(15):
            a.update(_metric_pose(k, True), 0)
            b.update(_metric_pose(k, True), 0)
        routes.alarm("s-b", "drone-b", "spoofing_alarm", "GPS disagrees with vision by 40 m")
        routes.alarm("s-b", "drone-b", "imu_gap", "not for the pilot")
        deadline = time.monotonic() + 0.5
        default.drain(deadline)
        own.drain(deadline + 0.1)
    finally:
        routes.close()
        default.close()
        own.close()
    texts = own.of_type("STATUSTEXT")
    assert [(m.severity, m.text) for m in texts] == [(2, "EVP drone-b: GPS disagrees with vision by 40 m")]
    assert not default.of_type("STATUSTEXT")
    assert {m.get_srcSystem() for m in default.of_type("ODOMETRY")} == {7}  # drone-a; drone-c sent nothing yet
    assert {m.get_srcSystem() for m in own.of_type("ODOMETRY")} == {7}
    assert not problems
