"""The handheld-pan scenario: a phone held 0.35 m ahead of a person turning on the spot."""

import numpy as np
import pytest

from evp.sim.scenarios import PAN_ARM_M, PAN_HALF_ANGLE_DEG, SimOptions, build_scenario


@pytest.mark.parametrize("speed", [0.3, 0.5])
def test_the_phone_sweeps_80_degrees_either_way_on_an_arc_and_its_fastest_point_moves_at_the_speed(speed):
    pan = build_scenario("handheld-pan", SimOptions(duration_s=20.0, seed=4, speed_m_s=speed))
    times = np.arange(0.0, 20.0, 0.01)
    poses = pan.camera_poses(times)
    axis = poses[:, :3, 2]
    heading = np.unwrap(np.arctan2(axis[:, 1], axis[:, 0]))
    sweep = np.degrees(heading - heading[0])
    assert sweep.max() == pytest.approx(PAN_HALF_ANGLE_DEG, abs=5.0)  # tilt and tremor add a little
    assert sweep.min() == pytest.approx(-PAN_HALF_ANGLE_DEG, abs=5.0)
    assert np.abs(sweep[times < 1.0]).max() < 3.0  # held still for the first second
    centre = poses[:, :2, 3] - PAN_ARM_M * axis[:, :2] / np.linalg.norm(axis[:, :2], axis=1, keepdims=True)
    assert np.ptp(centre, axis=0).max() < 0.1  # the turning axis stays put (tremor only)
    np.testing.assert_allclose(poses[:, 2, 3], 1.4, atol=0.05)
    arc_speed = np.abs(np.gradient(heading, times)) * PAN_ARM_M
    assert np.percentile(arc_speed, 99) == pytest.approx(speed, rel=0.1)
