"""The wheel-odometry filter on an exact synthetic planar drive with known beacons, and on bad
input."""

import math

import numpy as np
import pytest

from evp.fusion.odometry_filter import OdometryFilter, OdometryNoise, PlanarPose, multilaterate
from evp.types import BeaconRange, GpsFix, WheelOdometry

BEACONS = {"a": (-20.0, -15.0, 0.0), "b": (25.0, -10.0, 0.0), "c": (20.0, 30.0, 0.0), "d": (-15.0, 25.0, 0.0)}
BIAS_M = {"a": 1.5, "b": 0.0, "c": -0.8, "d": 0.4}
NOISE = OdometryNoise(speed_sigma_fraction=0.02, speed_sigma_m_s=0.02, yaw_rate_sigma_rad_s=0.02, range_sigma_m=0.2, range_bias_sigma_m=3.0)


def drive(seconds: float = 120.0, rate_hz: float = 10.0):
    """A figure of eight at 2 m/s: true poses and noisy odometry (2 % speed, 0.02 rad/s) at
    ``rate_hz``, ranges to one beacon in turn every 0.25 s with the seeded biases and 0.2 m noise."""
    rng = np.random.default_rng(7)
    times = np.arange(0.0, seconds + 1e-9, 1.0 / rate_hz)
    speed, yaw_rate = 2.0, 0.25 * np.sin(2 * np.pi * times / 50.0)
    yaw = np.concatenate([[0.0], np.cumsum(0.5 * (yaw_rate[1:] + yaw_rate[:-1]) / rate_hz)])
    mid = 0.5 * (yaw[1:] + yaw[:-1])
    xy = np.vstack([[0.0, 0.0], np.cumsum(speed / rate_hz * np.column_stack([np.cos(mid), np.sin(mid)]), axis=0)])
    odometry = [
        WheelOdometry(float(t), (), speed * (1 + 0.02 * rng.standard_normal()), float(d / (1 / rate_hz) + 0.02 * rng.standard_normal()))
        for t, d in zip(times[1:], np.diff(yaw))
    ]
    ranges = []
    names = list(BEACONS)
    for k, t in enumerate(np.arange(0.1, seconds, 0.25)):
        name = names[k % 4]
        true = np.array([np.interp(t, times, xy[:, 0]), np.interp(t, times, xy[:, 1])])
        distance = float(np.linalg.norm(true - np.array(BEACONS[name][:2])))
        ranges.append(BeaconRange(float(t), name, distance + BIAS_M[name] + 0.2 * rng.standard_normal()))
    return times, xy, yaw, odometry, ranges


def run(odometry, updates, flt):
    rows = []
    for record in sorted([*odometry, *updates], key=lambda r: r.timestamp):
        flt.add(record)
        if isinstance(record, WheelOdometry):
            rows.append(flt.state())
    return rows


def test_recovers_seeded_range_biases_and_stays_within_three_sigma():
    times, xy, _, odometry, ranges = drive()
    flt = OdometryFilter(NOISE, PlanarPose(0.0, 0.0, 0.0), 0.0, BEACONS)
    states = run(odometry, ranges, flt)
    errors = np.array([[s.x - x, s.y - y] for s, (x, y) in zip(states, xy[1:])])
    sigmas = np.sqrt(np.array([np.diag(s.position_covariance) for s in states]))
    assert np.all(np.abs(errors) <= 3 * sigmas)
    assert np.sqrt(np.mean(np.sum(errors**2, axis=1))) < 0.3
    for name, bias in BIAS_M.items():
        assert states[-1].range_biases_m[name] == pytest.approx(bias, abs=0.15)
    assert len(flt.innovations) == len(ranges) and np.mean([i.accepted for i in flt.innovations]) > 0.99  # the gate passes 99.73 %
    assert flt.warnings == []


def test_odometry_alone_drifts_and_the_gate_rejects_an_outlier():
    _, xy, _, odometry, ranges = drive(60.0)
    alone = run(odometry, [], OdometryFilter(NOISE, PlanarPose(0.0, 0.0, 0.0), 0.0, BEACONS))
    flt = OdometryFilter(NOISE, PlanarPose(0.0, 0.0, 0.0), 0.0, BEACONS)
    outlier = BeaconRange(30.05, "b", 80.0)
    fused = run(odometry, [*ranges, outlier], flt)
    assert np.linalg.norm([fused[-1].x - xy[-1, 0], fused[-1].y - xy[-1, 1]]) < np.linalg.norm([alone[-1].x - xy[-1, 0], alone[-1].y - xy[-1, 1]])
    rejected = {(i.timestamp, i.kind): i.nis for i in flt.innovations if not i.accepted}
    assert rejected[(30.05, "range:b")] > 100 and len(rejected) <= 4  # and a few consistent ones past 3 sigma


def test_bad_records_are_skipped_with_a_warning_and_lose_nothing():
    _, _, _, odometry, ranges = drive(20.0)
    clean = OdometryFilter(NOISE, PlanarPose(0.0, 0.0, 0.0), 0.0, BEACONS)
    run(odometry, ranges, clean)
    flt = OdometryFilter(NOISE, PlanarPose(0.0, 0.0, 0.0), 0.0, BEACONS)
    bad = [BeaconRange(5.05, "zz", 10.0), BeaconRange(6.05, "a", math.nan), WheelOdometry(7.05, (), math.nan, 0.0)]
    run(odometry, [*ranges, *bad], flt)
    flt.add(WheelOdometry(3.0, (), 2.0, 0.0))  # time going backwards
    flt.add(BeaconRange(1.0, "a", 10.0))  # far older than the filter
    assert len(flt.warnings) == 5
    assert any("'zz' not in the beacon list" in w for w in flt.warnings) and any("backwards" in w for w in flt.warnings)
    np.testing.assert_allclose([flt.state().x, flt.state().y], [clean.state().x, clean.state().y], atol=1e-9)
    assert len(flt.innovations) == len(ranges)


def test_gnss_fixes_correct_a_biased_speed_and_gyro():
    from evp.fusion.geodesy import EnuFrame

    frame = EnuFrame(45.0, 7.0, 200.0)
    times, xy, _, odometry, _ = drive(180.0)
    biased = [WheelOdometry(w.timestamp, (), 1.05 * w.forward_speed_m_s, w.yaw_rate_rad_s + 0.01) for w in odometry]
    fixes = [GpsFix(float(t), *frame.to_geodetic(np.array([x, y, 0.0]))[0]) for t, x, y in zip(times[5::10], xy[5::10, 0], xy[5::10, 1])]
    noise = OdometryNoise(0.01, 0.02, 0.005, gnss_sigma_m=1.0, scale_sigma=0.1, yaw_rate_bias_sigma_rad_s=0.02)
    flt = OdometryFilter(noise, PlanarPose(0.0, 0.0, 0.0), 0.0, gnss_frame=frame)
    state = run(biased, fixes, flt)[-1]
    assert 1 / state.speed_scale == pytest.approx(1.05, abs=0.01)
    assert state.yaw_rate_bias_rad_s == pytest.approx(0.01, abs=0.002)


def test_multilateration_finds_position_and_common_bias():
    truth = np.array([3.0, 4.0])
    ranges = [BeaconRange(0.0, n, float(np.linalg.norm(truth - np.array(p[:2]))) + 1.2) for n, p in BEACONS.items()]
    xy, covariance, bias = multilaterate(BEACONS, ranges, estimate_bias=True)
    np.testing.assert_allclose(xy, truth, atol=1e-6)
    assert bias == pytest.approx(1.2, abs=1e-6) and covariance.shape == (2, 2)
    with pytest.raises(ValueError, match="distinct beacons"):
        multilaterate(BEACONS, ranges[:2])
