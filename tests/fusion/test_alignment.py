"""The alignment recovers known transforms and clock offsets exactly, and refuses bad input."""

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from evp.config import AlignmentSettings
from evp.fusion.geodesy import EnuFrame
from evp.fusion.gps_alignment import align_flight, horizontal_errors_after
from evp.fusion.gps_input import AlignmentError, GpsTrack, clean_gps
from evp.sim.scenarios import SimOptions, build_scenario
from evp.types import GpsFix, Trajectory

FRAME = EnuFrame(43.72, 10.40, 4.0)


@pytest.fixture(scope="module")
def flight():
    """Ground truth of a simulated 160 s survey at 60 m: (camera times, positions) at 10 Hz."""
    scenario = build_scenario("drone-flight", SimOptions(duration_s=160.0, relief=False, speed_m_s=6.0))
    times = np.arange(0.0, 160.0, 0.1)
    return times, scenario.motion.state(times).position


def _gps(times, enu) -> GpsTrack:
    return GpsTrack(FRAME, times, enu, np.full(len(times), 1.5))


def _odometry(times, positions) -> Trajectory:
    return Trajectory(positions, np.tile([0.0, 0.0, 0.0, 1.0], (len(times), 1)), times)


def _baro(times, up) -> Trajectory:
    return Trajectory(np.column_stack([np.zeros(len(up)), np.zeros(len(up)), up]), np.tile([0.0, 0.0, 0.0, 1.0], (len(up), 1)), times)


def test_recovers_a_known_similarity_in_3d(flight):
    times, truth = flight
    R = Rotation.from_euler("zyx", [35, 8, -5], degrees=True).as_matrix()
    scale, shift = 0.02, np.array([3.0, -1.0, 0.5])
    odom = (truth - shift) @ R / scale  # inverse of enu = scale R odom + shift
    result = align_flight(_odometry(times, odom), _gps(times, truth), _baro(times, truth[:, 2]), AlignmentSettings(model="similarity", max_clock_offset_s=0.0))
    assert np.allclose(result.transform.matrix[:, :3], scale * R, atol=1e-9)
    assert np.allclose(result.transform.matrix[:, 3], shift, atol=1e-6)
    errors, _ = horizontal_errors_after(result, _gps(times, truth))
    assert errors.max() < 1e-6


def test_recovers_a_known_affine_in_2d_plus_baro(flight):
    times, truth = flight
    A = np.array([[0.03, 0.004], [-0.002, 0.025]])
    b = np.array([12.0, -7.0])
    odom_xy = np.linalg.solve(A, (truth[:, :2] - b).T).T
    odom = np.column_stack([odom_xy, np.random.default_rng(0).normal(0, 5, len(times))])  # odometry z is ignored in 2-D mode
    result = align_flight(
        _odometry(times, odom), _gps(times, truth), _baro(times, truth[:, 2]), AlignmentSettings(mode="2d+baro", model="affine", max_clock_offset_s=0.0)
    )
    assert np.allclose(result.transform.matrix, np.column_stack([A, b]), atol=1e-8)
    assert np.allclose(result.aligned.positions[:, 2], truth[:, 2])  # altitude from the barometer


def test_recovers_the_clock_offset(flight):
    times, truth = flight
    odom = truth * 0.05
    gps_clock = times + 0.4  # the GPS clock runs 0.4 s ahead of the camera's
    result = align_flight(_odometry(times, odom), _gps(gps_clock, truth), _baro(times, truth[:, 2]), AlignmentSettings(model="similarity"))
    assert result.clock_offset_s == pytest.approx(0.4, abs=0.02)
    errors, _ = horizontal_errors_after(result, _gps(gps_clock, truth))
    assert np.median(errors) < 0.1


def test_the_window_starts_at_target_altitude_and_lasts_70_s(flight):
    times, truth = flight
    result = align_flight(
        _odometry(times, truth), _gps(times, truth), _baro(times, truth[:, 2]), AlignmentSettings(target_altitude_m=60.3, max_clock_offset_s=0.0)
    )
    start, end = result.window
    first_reached = times[np.flatnonzero(np.abs(truth[:, 2] - 60.3) <= 5.0)[0]]
    assert start == pytest.approx(first_reached) and end - start == pytest.approx(70.0)


def test_noisy_gps_aligns_to_metre_level(flight):
    times, truth = flight
    rng = np.random.default_rng(1)
    gps = truth + rng.normal(0, 1.5, truth.shape)
    odom = truth * 0.01 + rng.normal(0, 0.002, truth.shape)
    result = align_flight(_odometry(times, odom), _gps(times, gps), _baro(times, truth[:, 2]), AlignmentSettings(max_clock_offset_s=0.0))
    aligned_error = np.linalg.norm(result.aligned.positions[:, :2] - truth[:, :2], axis=1)
    assert np.mean(aligned_error) < 0.5
    assert result.chosen["model"] in ("affine", "similarity")


def test_bad_gps_input_is_reported_not_hidden():
    fixes = [GpsFix(float(t), 43.72 + 1e-6 * t, 10.40, 4.0 + 0.1 * t) for t in range(50)]
    fixes[5] = GpsFix(5.0, math.nan, 10.40, 4.5)  # no lock
    fixes[10] = GpsFix(9.0, 43.72, 10.40, 5.0)  # out of order
    fixes[20] = GpsFix(20.0, 43.72, 10.40, 900.0)  # altitude jump
    track = clean_gps(fixes)
    assert len(track) == 47
    assert any("without lock" in w for w in track.warnings)
    assert any("out of time order" in w for w in track.warnings)
    assert any("altitude jumps" in w for w in track.warnings)
    with pytest.raises(AlignmentError, match="usable GPS fixes"):
        clean_gps([GpsFix(0.0, math.nan, math.nan, math.nan)])


def test_too_few_pairs_and_missing_barometer_are_errors(flight):
    times, truth = flight
    odom = _odometry(times[:3], truth[:3])
    with pytest.raises(AlignmentError, match="at least 6"):
        align_flight(odom, _gps(times, truth), None, AlignmentSettings())
    with pytest.raises(AlignmentError, match="needs barometer"):
        align_flight(_odometry(times, truth), _gps(times, truth), None, AlignmentSettings(mode="2d+baro"))
    with pytest.raises(AlignmentError, match="never reaches"):
        align_flight(_odometry(times, truth), _gps(times, truth), None, AlignmentSettings(target_altitude_m=300.0))
    late = _odometry(times + 1000.0, truth)  # no overlap in time with GPS
    with pytest.raises(AlignmentError, match="overlap|visual position"):
        align_flight(late, _gps(times, truth), None, AlignmentSettings())


def test_align_fraction_uses_the_first_fixes(flight):
    times, truth = flight
    result = align_flight(
        _odometry(times, truth * 2.0), _gps(times, truth), _baro(times, truth[:, 2]), AlignmentSettings(max_clock_offset_s=0.0), align_fraction=0.25
    )
    assert result.window == (times[0], times[int(round(0.25 * len(times))) - 1])
    with pytest.raises(AlignmentError, match="between 0 and 1"):
        align_flight(_odometry(times, truth), _gps(times, truth), None, AlignmentSettings(), align_fraction=1.5)


def test_a_straight_window_is_extended_back_to_take_off():
    """A straight leg cannot fix the rotation about itself; the vertical climb before it can."""
    times = np.arange(0.0, 120.0, 0.1)
    climb = np.clip(times / 20.0, 0.0, 1.0) * 60.0
    east = np.clip(times - 20.0, 0.0, None) * 5.0
    truth = np.column_stack([east, 0.2 * np.sin(times / 10.0), climb])
    R = Rotation.from_euler("zyx", [50, 20, 10], degrees=True).as_matrix()
    odom = truth @ R * 0.1
    settings = AlignmentSettings(model="similarity", target_altitude_m=60.0, window_s=60.0, max_clock_offset_s=0.0)
    result = align_flight(_odometry(times, odom), _gps(times, truth), _baro(times, truth[:, 2]), settings)
    assert any("nearly straight" in w for w in result.warnings)
    assert result.window[0] == times[0]
    assert np.allclose(result.transform.matrix[:, :3], 10.0 * R, atol=1e-6)  # enu = 10 R odom


def test_flat_pairs_do_not_get_an_unconstrained_affine(flight):
    """Pairs at one altitude are coplanar: a 3-D affine would be free across them."""
    times, truth = flight
    level = truth.copy()
    level[:, 2] = 60.0
    result = align_flight(
        _odometry(times, level * 0.1), _gps(times, level), None, AlignmentSettings(mode="3d+baro", max_clock_offset_s=0.0, target_altitude_m=60.0)
    )
    assert result.chosen["model"] == "similarity"
    assert any("affine fit" in w for w in result.warnings)


def test_too_few_pairs_to_hold_out_are_all_fitted_with_default_settings(flight):
    """A survey of ten photos: no pair can be spared for validation, so every pair is fitted with
    the default settings and the result says it was not validated."""
    times, truth = flight
    photos = np.linspace(0, len(times) - 1, 10).astype(int)
    R = Rotation.from_euler("zyx", [-70, 4, 2], degrees=True).as_matrix()
    odom = (truth[photos] - [1.0, 2.0, 0.0]) @ R / 0.05  # enu = 0.05 R odom + [1, 2, 0]
    settings = AlignmentSettings(max_clock_offset_s=0.0)
    result = align_flight(_odometry(times[photos], odom), _gps(times[photos], truth[photos]), None, settings, align_fraction=0.5)
    assert result.validation_rmse_m is None and result.pairs_used == 6
    assert result.chosen["model"] == "similarity" and result.chosen["ransac_threshold_m"] == max(settings.ransac_thresholds_m)
    assert any("too few to hold 3 out for validation" in w for w in result.warnings)
    assert np.allclose(result.transform.matrix[:, :3], 0.05 * R, atol=1e-9)
    errors, _ = horizontal_errors_after(result, _gps(times[photos], truth[photos]), max_gap_s=60.0)
    assert len(errors) == 4 and errors.max() < 1e-6
