"""The navigation filter's GPS error state: a first-order Gauss-Markov process, started by the
first fix or tied to the world's translation when the world was fitted to fixes."""

import math

import numpy as np
import pytest

from evp.config import NavigationSettings
from evp.fusion.measurements import GpsPosition
from evp.fusion.nav_state import GPS_BIAS, MAP_POSITION, POSITION, NavState
from evp.fusion.navigation_filter import NavigationFilter
from evp.types import ImuSample

RATE = 50.0  # at rest the rate does not matter; fewer steps keep the test cheap
SETTINGS = NavigationSettings(initial_yaw_sigma_rad=0.05)
ACCURACY = (1.5, 3.0)  # a fix's horizontal and vertical accuracy (1 sigma, m)
STATIONARY = (1.0 - SETTINGS.gps_white_share) * np.array([1.5**2 / 2, 1.5**2 / 2, 3.0**2])  # its correlated part, per axis


def _at_rest(duration_s: float, nav: NavigationFilter, start: float = 0.0) -> None:
    for k in range(int(round(duration_s * RATE)) + 1):
        nav.propagate(ImuSample(start + k / RATE, (0.0, 0.0, 0.0), (0.0, 0.0, SETTINGS.gravity_m_s2)))


def _filter() -> NavigationFilter:
    return NavigationFilter(NavState(0.0, np.zeros(3), np.zeros(3), np.eye(3)), SETTINGS)


def test_the_first_fix_starts_the_error_at_its_correlated_variance_and_it_decays_over_the_correlation_time():
    nav = _filter()
    _at_rest(1.0, nav)
    assert nav.state.gps_bias_variance is None  # no fix yet: the prior from the default accuracy
    assert nav.update(GpsPosition(1.0, (1.0, -0.5, 2.0), *ACCURACY)).accepted
    x, P = nav.state, nav.covariance
    assert np.allclose(x.gps_bias_variance, STATIONARY)
    bias, bias_covariance = x.gps_bias.copy(), P[GPS_BIAS, GPS_BIAS].copy()
    assert np.all(np.abs(bias) > 0.05)  # the fix's offset is shared between the position and the receiver
    tau = SETTINGS.gps_correlation_time_s
    _at_rest(tau, nav, start=1.0 + 1.0 / RATE)
    decay = math.exp(-(tau + 1.0 / RATE) / tau)
    assert np.allclose(nav.state.gps_bias, bias * decay, rtol=1e-9)
    expected = bias_covariance * decay**2 + np.diag(STATIONARY) * (1.0 - decay**2)
    assert np.allclose(nav.covariance[GPS_BIAS, GPS_BIAS], expected, rtol=1e-9, atol=1e-12)


def test_a_world_fitted_to_fixes_carries_their_error_so_the_next_fix_agrees_with_it():
    nav = _filter()
    _at_rest(1.0, nav)
    before = nav.covariance.copy()
    distortion = np.array([0.2, 0.2, 0.4])
    nav.move_world(np.eye(3), np.array([3.0, 4.0, 5.0]), np.zeros(3), distortion, 0.0, STATIONARY)
    P = nav.covariance
    assert np.allclose(nav.state.gps_bias, 0.0) and np.allclose(nav.state.gps_bias_variance, STATIONARY)
    assert np.allclose(P[POSITION, GPS_BIAS], -np.diag(STATIONARY))  # one error moved both, opposite ways in the error state
    assert np.allclose(P[GPS_BIAS, GPS_BIAS], np.diag(STATIONARY))
    assert np.allclose(P[MAP_POSITION, MAP_POSITION] - before[MAP_POSITION, MAP_POSITION], np.diag(distortion**2 + STATIONARY))
    # a fix predicts position + error: the shared part cancels, the distortion is what is left
    fix = P[POSITION, POSITION] + P[GPS_BIAS, GPS_BIAS] + P[POSITION, GPS_BIAS] + P[GPS_BIAS, POSITION]
    assert np.allclose(fix, before[POSITION, POSITION] + np.diag(distortion**2))


@pytest.mark.parametrize("seconds", [5.0, 120.0])
def test_a_constant_receiver_error_is_followed_only_as_far_as_the_correlation_time_lets_it(seconds):
    """Fixes 2 m east of the truth at rest: within seconds the offset is shared between the
    position and the receiver's error as their variances say (1 m^2 and 0.79 m^2 here), not
    taken for a position error; over minutes a receiver's error would have changed, so an
    offset that stays is the position's."""
    nav = _filter()
    _at_rest(0.02, nav)
    for k in range(1, int(seconds * 10) + 1):
        t = k / 10.0
        _at_rest(0.1 - 1.0 / RATE, nav, start=t - 0.1 + 1.0 / RATE)
        assert nav.update(GpsPosition(t, (2.0, 0.0, 0.0), *ACCURACY)).accepted
    east = nav.state.position[0]
    share = SETTINGS.initial_position_sigma_m**2 / (SETTINGS.initial_position_sigma_m**2 + STATIONARY[0])
    if seconds < 10:
        assert abs(east - 2.0 * share) < 0.15, east
    else:
        assert east > 1.8, east
