"""The autopilot over MAVLink, against a pymavlink listener playing the flight controller: no
set-point before it is armed in GUIDED, velocity set-points after, the watchdog holding when
frames stop, and the pilot's mode switch winning at once."""

import time

import numpy as np
import pytest

from evp.autopilot.pilot import Autopilot, OperatorCommand
from evp.config import AutopilotSettings, MarkerSettings
from tests.markers.synthetic import grid_positions, observe
from tests.station.conftest import free_port

mavutil = pytest.importorskip("pymavlink.mavutil")
MARKERS = grid_positions(5, 5)


class Clock:
    def __init__(self):
        self.now = 100.0

    def __call__(self):
        return self.now


def _heartbeat(controller, armed: bool, custom_mode: int) -> None:
    from pymavlink.dialects.v20 import common as mavlink

    base = mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | (mavlink.MAV_MODE_FLAG_SAFETY_ARMED if armed else 0)
    controller.mav.heartbeat_send(mavlink.MAV_TYPE_QUADROTOR, mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA, base, custom_mode, mavlink.MAV_STATE_ACTIVE)


def _setpoints(controller, timeout=0.3) -> list:
    found = []
    while (message := controller.recv_match(type="SET_POSITION_TARGET_LOCAL_NED", blocking=True, timeout=timeout)) is not None:
        found.append(message)
        timeout = 0.05
    return found


def _wait_for(predicate, link, seconds=2.0):
    for _ in range(int(seconds / 0.01)):
        link.poll()
        if predicate():
            return
        time.sleep(0.01)
    raise AssertionError("the link never saw the controller's heartbeat")


def test_setpoints_only_when_armed_in_guided_a_watchdog_hold_and_the_pilot_wins():
    from evp.station.mavlink_autopilot import ARDUCOPTER_GUIDED, VELOCITY_ONLY, MavlinkAutopilotLink

    port = free_port(kind=2)
    controller = mavutil.mavlink_connection(f"udpin:127.0.0.1:{port}", dialect="common")
    connection = mavutil.mavlink_connection(f"udpout:127.0.0.1:{port}", source_system=1, source_component=191, dialect="common")
    clock = Clock()
    pilot = Autopilot(AutopilotSettings(), MarkerSettings())
    link = MavlinkAutopilotLink(connection, pilot, clock)
    try:
        link.tick()  # our heartbeat tells the controller where we are
        assert controller.recv_match(type="HEARTBEAT", blocking=True, timeout=1.0) is not None
        link.on_frame(0.0, observe(np.array([0.4, 0.4]), 0.1, MARKERS), 0.1)
        assert _setpoints(controller) == [] and pilot.events[-1].kind == "no_setpoint"

        _heartbeat(controller, armed=True, custom_mode=ARDUCOPTER_GUIDED)
        _wait_for(lambda: link.in_control, link)
        for k in range(1, 40):  # lift-off, then a push east toward marker 14
            clock.now += 1 / 30
            link.on_frame(k / 30, observe(np.array([0.4, 0.4]), min(0.45, 0.1 + 0.4 * k / 30), MARKERS), min(0.45, 0.1 + 0.4 * k / 30))
        pilot.command(40 / 30, OperatorCommand("manual", velocity=(0.3, 0.0), duration_s=2.0))  # the operator's push wins
        clock.now += 1 / 30
        link.on_frame(41 / 30, observe(np.array([0.4, 0.4]), 0.45, MARKERS), 0.45)
        received = _setpoints(controller)
        assert len(received) >= 30 and all(m.type_mask == VELOCITY_ONLY and m.coordinate_frame == 8 for m in received)
        last = received[-1]
        assert last.vx == pytest.approx(0.0, abs=1e-6) and last.vy == pytest.approx(0.3, abs=1e-6)  # east = the body's right (heading north)

        clock.now += pilot.settings.frame_timeout_s + 0.1  # frames stop: the watchdog holds
        held = link.tick()
        assert held is not None and held.holding
        hold = _setpoints(controller)[-1]
        assert (hold.vx, hold.vy) == (0.0, 0.0)

        _heartbeat(controller, armed=True, custom_mode=5)  # the pilot flips to LOITER
        _wait_for(lambda: not link.in_control, link)
        clock.now += 0.1
        link.on_frame(3.0, observe(np.array([0.4, 0.4]), 0.45, MARKERS), 0.45)
        assert _setpoints(controller, timeout=0.2) == []
        assert any(e.kind == "manual_override" for e in pilot.events)
    finally:
        connection.close()
        controller.close()
