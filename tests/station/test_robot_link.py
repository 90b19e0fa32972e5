"""The wheel robot's link (seed 001): encoder counts streamed to a real station in-process (wraps
and jumps handled, recorded like all telemetry), a velocity command reaching the robot's client,
and the robot's watchdog stopping it when the commands stop (injected clock, no sleeps)."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from evp.config import RobotSettings, Settings
from evp.fusion.wheel_encoders import EncoderOdometry, tick_difference
from evp.mobile.client import StreamClient
from evp.mobile.robot import VelocityWatchdog, encoder_readings
from evp.mobile.sources import telemetry_message
from evp.station.auth import DEV
from evp.station.base_station import Station
from evp.station.protocol import PROTOCOL_VERSION, Hello, Velocity, decode_text, encode
from evp.station.store import SessionStore
from evp.types import EncoderCounts, WheelOdometry
from tests.station.conftest import committed, indexed_messages

ROBOT = RobotSettings(metres_per_tick=0.001, counter_bits=8, wheel_base_m=0.3)


def test_a_wrapped_counter_is_a_small_difference():
    assert tick_difference(4, 250, 8) == 10  # forward across the wrap
    assert tick_difference(250, 4, 8) == -10  # reverse across it
    assert tick_difference(65535, 0, 16) == -1 and tick_difference(3, 1, 16) == 2


def test_encoder_counts_round_trip_to_the_wheel_speeds_across_wraps():
    """The simulator's counts of 0.3 m/s wheels on an 8-bit counter of 1 mm ticks wrap every
    0.85 s; the speeds come back to within one tick per sample, the turn rate from the wheels."""
    times = np.arange(0, 4.0, 0.02)
    wheel = [WheelOdometry(float(t), (0.28, 0.32), 0.3, math.nan) for t in times]
    readings = list(encoder_readings(wheel, ROBOT))
    assert max(r.counts[0] for r in readings) == 255 and len({r.counts[1] for r in readings}) < len(readings)  # wrapped
    odometry = EncoderOdometry(ROBOT)
    records = [odometry.sample(r) for r in readings]
    assert records[0] is None and not odometry.warnings
    speeds = np.array([r.wheel_speeds_m_s for r in records[1:]])
    assert np.abs(speeds - [0.28, 0.32]).max() <= 0.001 / 0.02 + 1e-9
    assert np.mean([r.yaw_rate_rad_s for r in records[1:]]) == pytest.approx(0.04 / 0.3, rel=0.02)
    assert np.mean([r.forward_speed_m_s for r in records[1:]]) == pytest.approx(0.3, rel=0.01)


def test_a_jump_and_a_changed_counter_count_are_warned_not_driven():
    odometry = EncoderOdometry(RobotSettings(metres_per_tick=0.001, counter_bits=16, max_wheel_speed_m_s=2.0))
    odometry.sample(EncoderCounts(0.0, (100, 100), 0.1))
    jumped = odometry.sample(EncoderCounts(0.02, (100 + 20000, 101), 0.1))  # 1000 m/s: a reset, not motion
    assert math.isnan(jumped.forward_speed_m_s) and jumped.yaw_rate_rad_s == 0.1
    assert "encoder jump" in odometry.warnings[-1]
    assert odometry.sample(EncoderCounts(0.04, (20105, 106), 0.1)).wheel_speeds_m_s == pytest.approx((0.25, 0.25))
    assert odometry.sample(EncoderCounts(0.06, (1,), 0.1)) is None and "counters" in odometry.warnings[-1]
    assert odometry.sample(EncoderCounts(0.06, (2,), 0.1)) is None and "not after" in odometry.warnings[-1]


def test_the_watchdog_stops_the_robot_when_commands_stop():
    watchdog = VelocityWatchdog(timeout_s=0.5)
    command = Velocity(linear_m_s=0.3, angular_rad_s=0.2)
    for t in (0.0, 0.1, 0.2):  # the station repeating its command
        watchdog.command(command, t)
        assert watchdog.velocity(t + 0.05) == (0.3, 0.2)
    assert watchdog.velocity(0.7) == (0.3, 0.2)  # 0.5 s after the last: not yet
    assert watchdog.velocity(0.7001) == (0.0, 0.0) and watchdog.stops == 1
    assert watchdog.velocity(5.0) == (0.0, 0.0) and watchdog.stops == 1  # stays stopped, counted once
    watchdog.command(command, 6.0)
    assert watchdog.velocity(6.1) == (0.3, 0.2)


def test_a_station_receives_ticks_and_drives_the_robot(tmp_path):
    """In-process station: the encoder counts are recorded verbatim and reach the estimator's batch
    as wheel records (a wrap and a jump among them); the operator's command reaches the robot's
    client, is repeated every command_interval_s while it drives, and after the link drops the
    robot's watchdog stops it; a reconnect does not set it moving again."""
    settings = Settings.model_validate({"robot": ROBOT.model_dump()})
    station = Station(tmp_path / "data", settings)
    try:
        session, _ = station.open_session(Hello(protocol=PROTOCOL_VERSION, device="robot"), DEV)
        robot_clock = {"now": 0.0}
        watchdog = VelocityWatchdog(settings.robot.watchdog_timeout_s)
        client = StreamClient("ws://127.0.0.1:1", on_velocity=lambda m: watchdog.command(m, robot_clock["now"]), log=lambda _text: None)
        session.attach(lambda text: client._handle(decode_text(text)))
        session.worker = object()  # an estimator is attached: telemetry is batched for it

        readings = [EncoderCounts(0.0, (250, 250), 0.0), EncoderCounts(0.02, (4, 6), 0.0), EncoderCounts(0.04, (200, 10), 0.0)]
        for k, reading in enumerate(readings):
            session.on_text(encode(telemetry_message(reading)), 100.0 + k)
        batch = session._telemetry_batch
        assert [type(r) for r in batch] == [WheelOdometry, WheelOdometry]
        assert batch[0].wheel_speeds_m_s == pytest.approx((0.5, 0.6))  # 10 and 12 ticks across the wrap
        assert math.isnan(batch[1].forward_speed_m_s)  # 196 ticks in 20 ms: a jump
        committed(lambda: any(e["code"] == "encoder" for e in station.store.recent_events(20)), "the jump's warning")

        session.drive(0.3, 0.1, 200.0)
        assert client.report.velocity_commands == 1 and watchdog.velocity(0.0) == (0.3, 0.1)
        session.repeat_drive(200.05)  # not due yet
        robot_clock["now"] = 0.1
        session.repeat_drive(200.11)
        assert client.report.velocity_commands == 2
        session.detach(clean=False)  # the link drops: nothing reaches the robot any more
        session.repeat_drive(200.3)
        assert client.report.velocity_commands == 2
        session.attach(lambda text: client._handle(decode_text(text)))  # back: no motion without a new command
        session.repeat_drive(201.0)
        assert client.report.velocity_commands == 2
        assert watchdog.velocity(0.1 + settings.robot.watchdog_timeout_s + 1e-3) == (0.0, 0.0) and watchdog.stops == 1
        session.recording.close()
    finally:
        station.store.close()
    store = SessionStore(station.store.url)
    try:
        rows = store.rows("telemetry", session.id)
        assert [r["kind"] for r in rows] == ["encoder"] * 3 and json.loads(rows[1]["data_json"])["counts"] == [4, 6]
    finally:
        store.close()
    texts = [m.data for topic, _, m in indexed_messages(session.recording.path) if topic == "/evp/messages"]
    assert sum('"encoder"' in t for t in texts) == 3 and sum('"velocity"' in t for t in texts) == 1


def test_a_velocity_command_is_clamped_and_zero_is_not_repeated(tmp_path):
    from evp.station.robot_link import RobotLink

    link = RobotLink(RobotSettings(max_linear_m_s=0.5, max_angular_rad_s=1.0))
    sent = link.drive(3.0, -9.0, 0.0)
    assert (sent.linear_m_s, sent.angular_rad_s) == (0.5, -1.0)
    assert link.due(0.05) is None and link.due(0.1) == sent
    assert link.drive(0.0, 0.0, 0.2).linear_m_s == 0.0 and link.due(5.0) is None
    with pytest.raises(ValueError, match="not finite"):
        link.drive(math.nan, 0.0, 0.0)
