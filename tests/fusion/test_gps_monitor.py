"""Spoofing and jamming detection meets its figures on seeded simulations."""

import pytest

from evp.config import MonitorSettings
from evp.fusion.gps_monitor import GpsMonitor, GpsTrust
from evp.sim.monitor_trials import first, monitor_run
from evp.sim.sensors import GpsConfig


@pytest.mark.parametrize("seed", range(3))
def test_a_5_m_s_pull_off_is_flagged_within_5_s(seed):
    monitor = monitor_run(GpsConfig(spoof_start_s=150.0, spoof_mode="pull", spoof_rate_m_s=5.0, spoof_direction_deg=60.0 * seed), seed)
    alarm = first(monitor, "spoofing_alarm")
    assert alarm is not None and 150.0 <= alarm <= 155.0


@pytest.mark.parametrize("seed", range(3))
def test_a_50_m_jump_is_flagged_within_1_s(seed):
    monitor = monitor_run(GpsConfig(spoof_start_s=150.0, spoof_mode="jump", spoof_jump_m=50.0, spoof_direction_deg=90.0 * seed), seed)
    alarm = first(monitor, "spoofing_alarm")
    assert alarm is not None and 150.0 <= alarm <= 151.0
    assert monitor.trust is GpsTrust.UNTRUSTED  # a spoofer that stays is never trusted again


def test_no_false_alarm_in_an_hour_of_clean_flights():
    """12 flights of 300 s (230 s each after alignment, 46 minutes) plus 4 of 400 s: over an hour."""
    flights = [(seed, 300.0) for seed in range(12)] + [(100 + seed, 400.0) for seed in range(4)]
    total = 0.0
    for seed, duration in flights:
        monitor = monitor_run(GpsConfig(), seed, duration)
        assert first(monitor, "spoofing_alarm") is None, f"false alarm in flight {seed}: {monitor.events}"
        total += duration - 70.0
    assert total >= 3600.0


def test_a_60_s_jamming_outage_is_reported_and_recovered_from():
    monitor = monitor_run(GpsConfig(outages=[(120.0, 60.0)]), seed=5)
    lost = first(monitor, "gps_lost")
    back = first(monitor, "gps_back")
    assert lost is not None and 121.9 <= lost <= 122.5  # noticed 2 s (the outage timeout) after the last fix
    assert back is not None and back == pytest.approx(180.0, abs=0.2)
    assert first(monitor, "spoofing_alarm") is None
    assert first(monitor, "trust_restored") is not None  # consistent again after the outage


def test_trust_returns_only_after_a_sustained_consistent_period():
    monitor = GpsMonitor(MonitorSettings(recovery_s=5.0))
    t = 0.0

    def feed(until: float, offset: float) -> None:
        nonlocal t
        while t < until - 1e-9:
            monitor.update(t, [offset, 0.0], [0.0, 0.0], 0.0)
            t = round(t + 0.1, 6)

    feed(2.0, 0.0)
    monitor.update(2.0, [40.0, 0.0], [0.0, 0.0], 0.0)  # one wild fix is averaged away, not an alarm
    t = 2.1
    assert monitor.trust is GpsTrust.TRUSTED
    feed(3.0, 40.0)  # a sustained 40 m disagreement is
    assert monitor.trust is GpsTrust.UNTRUSTED
    feed(8.5, 0.0)  # consistent again once the window has cleared (t ~ 4 s), but not yet for 5 s
    assert monitor.trust is GpsTrust.UNTRUSTED
    feed(9.5, 0.0)
    assert monitor.trust is GpsTrust.TRUSTED
    assert [e.kind for e in monitor.events] == ["spoofing_alarm", "trust_restored"]
