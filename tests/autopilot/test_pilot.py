"""The autopilot's decisions on synthetic observations: the state machine, the counter-steer vote
(Eq. 4) and its handling of bad input (each logged, never a fly-away)."""

import numpy as np

from evp.autopilot.edge_vote import counter_steer
from evp.autopilot.pilot import Autopilot, OperatorCommand, State
from evp.config import AutopilotSettings, MarkerSettings
from tests.markers.synthetic import grid_positions, observe

MARKERS = grid_positions(5, 5)


def _airborne(pilot: Autopilot, frames: int = 60, xy=(0.4, 0.4)) -> float:
    t = 0.0
    for k in range(frames):
        t = k / 30
        height = min(0.45, 0.1 + 0.4 * t)
        pilot.step(t, observe(np.array(xy), height, MARKERS), height)
    return t


def test_lift_off_then_exploration_at_the_flight_level():
    pilot = Autopilot(AutopilotSettings(), MarkerSettings())
    command = pilot.step(0.0, observe(np.array([0.4, 0.4]), 0.1, MARKERS), 0.1)
    assert pilot.state == State.LIFT_OFF and command.climb_m_s > 0 and command.motors
    _airborne(pilot)
    assert pilot.state in (State.EXPLORATION, State.NAVIGATION)
    assert any("flight level reached" in e.detail for e in pilot.events)


def test_a_command_to_a_marker_not_in_the_map_is_rejected_and_logged():
    pilot = Autopilot(AutopilotSettings(), MarkerSettings())
    t = _airborne(pilot)
    assert not pilot.command(t, OperatorCommand("goto", marker_id=77))
    assert pilot.events[-1].kind == "command_rejected" and "77" in pilot.events[-1].detail
    assert pilot.command(t, OperatorCommand("goto", marker_id=12))


def test_frames_stopping_hold_then_land():
    settings = AutopilotSettings()
    pilot = Autopilot(settings, MarkerSettings())
    t = _airborne(pilot)
    held = pilot.step(t + settings.frame_timeout_s + 0.1, None, 0.45)
    assert held.holding and np.allclose(held.velocity_map, 0.0) and pilot.state != State.LAND
    pilot.step(t + settings.land_after_s + 0.1, None, 0.45)
    assert pilot.state == State.LAND
    landed = pilot.step(t + settings.land_after_s + 0.2, None, 0.05)
    assert pilot.state == State.LANDED and not landed.motors
    assert [e.detail for e in pilot.events if e.kind == "frames_stopped"][-1].endswith("landing")


def test_a_lone_copy_of_a_mapped_marker_does_not_teleport_the_vehicle():
    pilot = Autopilot(AutopilotSettings(), MarkerSettings())
    t = _airborne(pilot)
    before = pilot.position[:2].copy()
    copy = {6: np.array([0.5, 0.5])}  # mapped marker 6 again, 0.43 m from the real one, nothing else in view
    pilot.step(t + 1 / 30, observe(np.array([0.4, 0.4]), 0.45, copy, reach=0.15), 0.45)
    assert np.linalg.norm(pilot.position[:2] - before) < 0.05
    assert any(e.kind == "duplicate_id" for e in pilot.marker_map.events)


def test_a_range_dropout_falls_back_to_the_markers_height():
    pilot = Autopilot(AutopilotSettings(), MarkerSettings())
    t = _airborne(pilot)
    for k in range(1, 20):
        pilot.step(t + k / 30, observe(np.array([0.4, 0.4]), 0.6, MARKERS), float("nan"))
    assert pilot.height_m == np.float64(0.6) or abs(pilot.height_m - 0.6) < 1e-6
    assert any(e.kind == "range_dropout" for e in pilot.events)


def test_losing_the_markers_at_a_tracking_height_is_the_edge_and_the_vote_steers_back():
    settings = AutopilotSettings()
    pilot = Autopilot(settings, MarkerSettings())
    t = _airborne(pilot, xy=(0.75, 0.4))
    command = None
    for k in range(1, 30):
        command = pilot.step(t + k / 30, [], 0.45)
    assert pilot.state == State.EDGE
    assert command.velocity_map[0] < 0  # the map lies west of the exit


def test_a_diagonal_exit_at_a_corner_gets_a_diagonal_counter_steer():
    vote = counter_steer(
        exit_position=np.array([1.0, 1.0]),
        last_marker=np.array([0.8, 0.8]),
        map_centre=np.zeros(2),
        map_half_extent=np.array([0.8, 0.8]),
        mapped_markers=99,
        drift_velocity=np.array([0.1, 0.02]),
        pitch_m=0.196,
        weights=(2.0, 1.0, 1.0),
    )
    assert vote.counter_steer[0] < 0 and vote.counter_steer[1] < 0
