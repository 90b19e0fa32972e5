"""GPS through the navigation stage: exact visual poses and IMU of a known trajectory (as in
test_navigation_stage.py) plus GPS fixes of the same trajectory, spoofed, jammed or without lock."""

import numpy as np

from evp.config import NavigationSettings
from evp.fusion.geodesy import EnuFrame
from evp.fusion.gps_monitor import GpsTrust
from evp.types import GpsFix, PoseEstimate, TrackingState
from tests.fusion.inertial_trajectory import SinusoidTrajectory, imu_times
from tests.fusion.test_navigation_stage import FRAME_RATE, MAP_SCALE, _run, map_pose

ORIGIN = EnuFrame(43.7238, 10.3966, 4.0)  # the truth's world is ENU here
DURATION_S = 25.0
GPS_RATE_HZ = 10.0
# the test trajectory cruises at ~1.1 m/s: 1.5 m of spread (RMS) is reached ~5 s after the start
SETTINGS = NavigationSettings(gps_align_min_spread_m=1.5)


def _fixes(trajectory, offset=lambda t: np.zeros(3), outages=(), no_lock=()):
    """Exact fixes of the trajectory at 10 Hz, ``offset(t)`` (ENU, m) added; none inside ``outages``
    and NaN ones inside ``no_lock`` ((start, end) seconds)."""
    fixes = []
    for t in np.arange(0.0, DURATION_S, 1.0 / GPS_RATE_HZ):
        if any(a <= t < b for a, b in outages):
            continue
        lat, lon, alt = ORIGIN.to_geodetic(trajectory.position(t) + offset(t))[0]
        if any(a <= t < b for a, b in no_lock):
            lat = lon = alt = float("nan")
        fixes.append(GpsFix(float(t), lat, lon, alt, 1.0, 2.0))
    return fixes


def _run_with_gps(fixes, settings=SETTINGS):
    trajectory = SinusoidTrajectory()
    times = np.arange(0.0, DURATION_S, 1.0 / FRAME_RATE)
    estimates = [PoseEstimate(float(t), map_pose(trajectory, t), TrackingState.OK) for t in times]
    telemetry = sorted(trajectory.imu(imu_times(DURATION_S)) + fixes, key=lambda r: r.timestamp)
    return _run(estimates, telemetry, settings=settings)


def _horizontal_errors(trajectory, stage, result):
    """Horizontal error (m) of each georeferenced estimate against the truth in ENU at the take-off point."""
    georeferenced = [e for e in result.estimates if e.georeferenced]
    times = np.array([e.timestamp for e in georeferenced])
    truth = stage.enu_frame.to_enu(*ORIGIN.to_geodetic(trajectory.position(times)).T)
    from tests.fusion.test_navigation_filter import T_BODY_CAM

    body = np.array([e.T_world_cam @ np.linalg.inv(T_BODY_CAM) for e in georeferenced])[:, :3, 3]
    return times, np.linalg.norm(body[:, :2] - truth[:, :2], axis=1)


def test_trusted_gps_puts_the_track_in_enu_at_the_take_off_point():
    trajectory = SinusoidTrajectory()
    stage, result = _run_with_gps(_fixes(trajectory))
    assert stage.world_alignment is not None and stage.gps_monitor.trust is GpsTrust.TRUSTED
    times, errors = _horizontal_errors(trajectory, stage, result)
    assert len(times) > 300 and errors.max() < 0.05  # metres, no alignment at all
    assert result.estimates[-1].gps_trusted and "gps" in stage.sensors_used
    assert not stage.warnings


def test_a_spoofers_pull_off_never_enters_the_state():
    trajectory = SinusoidTrajectory()
    start, rate = 12.0, 5.0  # the spoofer pulls GPS east at 5 m/s from 12 s: 65 m off at the end
    stage, result = _run_with_gps(_fixes(trajectory, offset=lambda t: np.array([rate * max(0.0, t - start), 0.0, 0.0])))
    times, errors = _horizontal_errors(trajectory, stage, result)
    # the first 0.6 s of pull-off (3 m) pass the filter's gate fix by fix (a GPS error that
    # size is within the receiver's correlated error) and move the state by ~0.3 m; then the gate
    # refuses it, and 3.6 s after its start the monitor untrusts GPS
    assert errors.max() < 0.6, errors.max()  # while GPS drifts 65 m
    # nothing more of it after: the 0.2 m is drift from the velocity the first fixes bent
    assert errors[-1] <= errors[times <= start + 2.0][-1] + 0.2
    assert [e.kind for e in stage.gps_monitor.events] == ["spoofing_alarm"]
    assert not result.estimates[-1].gps_trusted and result.estimates[-1].georeferenced
    late = [r for r in stage.gps_records if r.timestamp > start + 2.0]
    assert late and not any(r.update is not None and r.update.accepted for r in late)


def test_a_jamming_gap_keeps_the_filter_on_vision_and_imu():
    trajectory = SinusoidTrajectory()
    stage, result = _run_with_gps(_fixes(trajectory, outages=[(10.0, 14.5)]))
    assert all(e.metric for e in result.estimates if e.timestamp >= stage.initialised_at)
    times, errors = _horizontal_errors(trajectory, stage, result)
    assert errors[(times > 10.0) & (times < 14.5)].max() < 0.05
    # back after 4.5 s, trusted again after recovery_s (10 s) of consistent fixes
    assert [e.kind for e in stage.gps_monitor.events] == ["gps_lost", "gps_back", "trust_restored"]
    assert any("no GPS fix for" in w for w in stage.warnings)


def test_fixes_without_lock_give_one_specific_warning_and_gps_off_is_off():
    trajectory = SinusoidTrajectory()
    stage, result = _run_with_gps(_fixes(trajectory, no_lock=[(8.0, 9.0)]))
    assert [w for w in stage.warnings if "no lock" in w] == ["GPS fix at 8.000 s has no lock (NaN or infinite position): GPS not fused until a fix has one"]
    assert result.estimates[-1].gps_trusted
    stage, result = _run_with_gps(_fixes(trajectory), SETTINGS.model_copy(update={"use_gps": False}))
    assert stage.enu_frame is None and not any(e.georeferenced for e in result.estimates)


def test_the_heading_fit_recovers_a_turn_and_a_shift():
    from evp.fusion.gps_heading import align_to_gps

    local = np.random.default_rng(0).normal(size=(30, 3)) * [20.0, 10.0, 1.0]
    yaw = 2.5
    R = np.array([[np.cos(yaw), -np.sin(yaw), 0.0], [np.sin(yaw), np.cos(yaw), 0.0], [0.0, 0.0, 1.0]])
    fit = align_to_gps(local, local @ R.T + [100.0, -50.0, 3.0], gps_sigma_m=1.5)
    np.testing.assert_allclose(fit.R, R, atol=1e-12)
    np.testing.assert_allclose(fit.t, [100.0, -50.0, 3.0], atol=1e-9)
    assert 0.05 < fit.yaw_sigma_rad < 0.1  # 1.5 m over ~22 m of spread


def test_gps_lost_before_the_heading_fit_fits_it_on_the_track_it_has_when_that_is_worth_it():
    """Jammed 15 s after take-off, before the fixes spread the 50 m asked here: the heading is
    fitted on the track they have when its uncertainty (a fix's error over their spread) is within
    the setting, with a warning, and GPS is unavailable; else one warning and no georeference."""
    trajectory = SinusoidTrajectory()
    fixes = _fixes(trajectory, outages=[(15.0, DURATION_S)])
    lenient = SETTINGS.model_copy(update={"gps_align_min_spread_m": 50.0, "gps_align_on_loss_max_heading_sigma_deg": 45.0})
    stage, result = _run_with_gps(fixes, lenient)
    assert stage.world_alignment is not None and stage.gps_state == "unavailable"
    assert [n.code for n in stage.notices if n.level == "warning"] == ["georeferenced_short_track"]
    times, errors = _horizontal_errors(trajectory, stage, result)
    assert times[0] > 15.0 + stage.gps_monitor.settings.outage_s - 0.1  # told by the fixes' absence
    assert errors.max() < 0.1  # exact fixes: the fit is exact whatever its spread

    strict = lenient.model_copy(update={"gps_align_on_loss_max_heading_sigma_deg": 1.0})
    stage, result = _run_with_gps(fixes, strict)
    assert stage.world_alignment is None and not any(e.georeferenced for e in result.estimates)
    assert [n.code for n in stage.notices if n.level == "warning"] == ["not_georeferenced"]


def test_gps_lost_holds_the_map_fitted_to_the_trusted_fixes_until_gps_is_trusted_again():
    """The jamming gap of the test above: at the loss the visual map's scale and pose are fitted to
    the fixes so far and held (no update moves the scale), released once GPS is trusted again."""
    trajectory = SinusoidTrajectory()
    stage, result = _run_with_gps(_fixes(trajectory, outages=[(10.0, 14.5)]))
    codes = [(n.code, round(n.timestamp, 2)) for n in stage.notices if n.code.startswith("map")]
    assert [c for c, _ in codes] == ["map_held", "map_released"]
    held, released = codes[0][1], codes[1][1]
    assert 11.9 <= held <= 12.1  # gps_monitor.outage_s after the last fix
    during = [r.output.scale for r in stage.records if held < r.output.timestamp < released]
    assert len(during) > 100 and max(during) == min(during)
    fitted = next(n.text for n in stage.notices if n.code == "map_held")
    assert "fitted to" in fitted and "held until GPS is trusted again" in fitted
    assert abs(during[0] / MAP_SCALE - 1) < 0.01
    stage, _ = _run_with_gps(_fixes(trajectory, outages=[(10.0, 14.5)]), SETTINGS.model_copy(update={"hold_map_on_gps_loss": False}))
    assert not [n for n in stage.notices if n.code.startswith("map")]
