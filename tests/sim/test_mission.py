"""Closed-loop missions at a reduced scale (240x180 renders, a few seconds each): the autopilot's
commands move the simulated quadrotor and its camera sees the result."""

import json

import numpy as np

from evp.autopilot.pilot import OperatorCommand, State
from evp.sim.mission import ROOM_HALF_M, MissionSpec, fly
from tests.cli.conftest import evp

SMALL = (240, 180)
REQUIRED = {"landed", "landing_error_m", "markers_mapped", "markers_total", "mission_time_s", "left_room", "frame_ms_p95"}


def test_evp_fly_lands_on_the_target_marker_and_writes_the_mission(tmp_path):
    run = evp("fly", "marker-field", "--target", 40, "--seed", 3, "--duration", 25, "--resolution", "240x180", "--out", tmp_path)
    assert run.returncode == 0, run.stderr
    mission = json.loads((tmp_path / "mission.json").read_text())
    assert REQUIRED <= set(mission)
    assert mission["landed"] and not mission["left_room"]
    assert mission["landing_error_m"] < 0.05
    assert mission["markers_total"] == 99 and mission["markers_mapped"] >= 6
    assert mission["flight_level_in_band_fraction"] >= 0.98
    for name in ("trajectory.csv", "map.json", "events.json", "timeline.csv", "flight_level.png", "exploration.png", "top_view.png"):
        assert (tmp_path / name).stat().st_size > 0
    states = [line.split(",")[1] for line in (tmp_path / "timeline.csv").read_text().splitlines()[1:]]
    assert states[0] == "lift_off" and states[-1] == "landed" and "land" in states


def test_a_push_off_the_corner_is_recovered_by_the_counter_steer():
    push = OperatorCommand("manual", velocity=(-0.25, -0.25), duration_s=1.5)  # off corner marker 0, diagonally
    result = fly(MissionSpec(seed=5, start_marker=0, duration_s=8.0, resolution=SMALL, commands=[(2.0, push)]))
    over = result.over_map()
    off = np.flatnonzero(~over & (result.times >= 2.0))
    assert len(off), "the push should have left the map"
    assert over[off[0] :].any(), "the vehicle should be back over the map"
    kinds = [e.kind for e in result.autopilot.events]
    assert "edge" in kinds and "edge_lost" not in kinds
    assert not result.left_room and np.all(np.abs(result.true_positions[:, :2]) < ROOM_HALF_M)


def test_frames_stopping_make_it_hold_then_land_in_place():
    result = fly(MissionSpec(seed=2, hover_s=30.0, duration_s=12.0, resolution=SMALL, frame_gaps=[(3.0, 60.0)]))
    assert result.autopilot.state == State.LANDED and not result.left_room
    kinds = [e.detail for e in result.autopilot.events if e.kind == "frames_stopped"]
    assert kinds[0].endswith("holding") and kinds[-1].endswith("landing")
    drifted = np.linalg.norm(result.true_positions[-1, :2] - result.true_positions[np.searchsorted(result.times, 3.0), :2])
    assert drifted < 1.0


def test_a_land_command_to_an_unmapped_marker_is_refused_and_the_flight_goes_on():
    result = fly(MissionSpec(seed=4, hover_s=5.0, duration_s=10.0, resolution=SMALL, commands=[(2.0, OperatorCommand("land", marker_id=98))]))
    assert any(e.kind == "command_rejected" and "98" in e.detail for e in result.autopilot.events)
    assert result.autopilot.state == State.LANDED and not result.left_room
