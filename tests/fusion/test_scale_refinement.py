"""The map's scale refined again after the start (ORB-SLAM3's inertial-only re-runs): the
refinement over the keyframes since the map began recovers a scale the filter started off, the
filter takes it in place of its own with the body carried where the map has it, and a scale the
filter knows better (or holds from GPS) is left."""

import math

import numpy as np
import pytest

from evp.config import NavigationSettings
from evp.fusion.innovation import UpdateStatus
from evp.fusion.measurements import RefinedScale, VisualPose
from evp.fusion.nav_state import ERROR_DIM, LOG_SCALE, POSITION, NavState
from evp.fusion.navigation_filter import NavigationFilter, initial_covariance
from evp.fusion.scale_refinement import REFINE_AFTER_S, ScaleRefinement
from evp.types import ImuSample, PoseEstimate, TrackingState
from tests.fusion.inertial_trajectory import GRAVITY, SinusoidTrajectory, imu_times
from tests.fusion.test_navigation_filter import MAP_SCALE, R_WORLD_MAP, T_BODY_CAM, T_WORLD_MAP
from tests.fusion.test_navigation_stage import FRAME_RATE, _run, map_pose
from tests.fusion.test_visual_inertial_init import GYRO_BIAS, keyframes

ACCEL_BIAS = np.array([0.15, -0.2, 0.1])
# a slow walk-like motion: the scale barely separates from the accelerometer bias at first
SLOW = SinusoidTrajectory(amplitude=(1.0, 0.7, 0.2), cruise=(0.3, 0.1, 0.0))


def _anchored_filter(scale: float, scale_sigma: float, covariance: np.ndarray | None = None) -> NavigationFilter:
    at_rest = ImuSample(0.0, (0.0, 0.0, 0.0), (0.0, 0.0, GRAVITY))
    state = NavState(
        0.0,
        np.array([2.0, -1.0, 0.5]),
        np.array([0.4, 0.3, 0.0]),
        np.eye(3),
        log_scale=math.log(scale),
        R_world_map=R_WORLD_MAP,
        t_world_map=np.array([0.3, 0.2, 0.1]),
        map_anchored=True,
    )
    P = initial_covariance(NavigationSettings()) if covariance is None else covariance
    P[POSITION, POSITION] = np.eye(3) * 1e-4 if covariance is None else P[POSITION, POSITION]
    P[LOG_SCALE, LOG_SCALE] = scale_sigma**2 if covariance is None else P[LOG_SCALE, LOG_SCALE]
    nav = NavigationFilter(state, NavigationSettings(), P)
    nav.propagate(at_rest)
    return nav


def test_a_refined_scale_replaces_the_filters_and_the_body_stays_where_the_map_has_it():
    nav = _anchored_filter(scale=3.0, scale_sigma=0.1)
    before = nav.state
    seen = VisualPose(0.0, np.eye(4), T_BODY_CAM)  # any map pose: what the state predicts the map sees
    predicted = seen.linearise(before, np.zeros(3), nav.settings).residual
    innovation = nav.update(RefinedScale(0.0, 3.6, 0.02, T_BODY_CAM))
    assert innovation.status is UpdateStatus.ACCEPTED
    after = nav.state
    assert after.scale == pytest.approx(3.6, rel=1e-12)  # replaced, not averaged with the filter's 3.0
    assert np.sqrt(nav.covariance[LOG_SCALE, LOG_SCALE]) == pytest.approx(0.02, rel=1e-9)
    # the camera's place in the map and the velocity through it are the same: they grew with the scale
    assert np.allclose(seen.linearise(after, np.zeros(3), nav.settings).residual, predicted, atol=1e-12)
    assert np.allclose(after.velocity, 1.2 * before.velocity)
    # the position's uncertainty along the camera's offset is now the new scale's (it was 1 cm)
    offset = after.position + T_BODY_CAM[:3, 3] - after.t_world_map
    along = offset / np.linalg.norm(offset)
    assert along @ nav.covariance[POSITION, POSITION] @ along == pytest.approx(1e-4 + (0.02 * np.linalg.norm(offset)) ** 2, rel=0.01)


def test_the_body_stays_where_the_map_has_it_whatever_the_filter_s_correlations():
    """After visual updates the scale's error is correlated with the map's pose and the body's
    attitude; those stay, and the camera's pose in the map is predicted as before."""
    rng = np.random.default_rng(5)
    A = rng.normal(size=(ERROR_DIM, ERROR_DIM)) * 0.05
    nav = _anchored_filter(scale=3.0, scale_sigma=0.1, covariance=A @ A.T + np.eye(ERROR_DIM) * 1e-4)
    before = nav.state
    seen = VisualPose(0.0, np.eye(4), T_BODY_CAM)
    predicted = seen.linearise(before, np.zeros(3), nav.settings).residual
    nav.update(RefinedScale(0.0, 3.6, 0.02, T_BODY_CAM))
    assert nav.state.scale == pytest.approx(3.6, rel=1e-12)
    assert np.allclose(seen.linearise(nav.state, np.zeros(3), nav.settings).residual, predicted, atol=1e-12)
    assert np.all(np.linalg.eigvalsh(nav.covariance) > 0)


def test_a_held_scale_is_not_replaced():
    nav = _anchored_filter(scale=3.0, scale_sigma=0.1)
    x = nav.state
    nav.hold_map(x.log_scale, x.R_world_map, x.t_world_map, np.eye(7) * 1e-4)
    innovation = nav.update(RefinedScale(0.0, 3.6, 0.02, T_BODY_CAM))
    assert innovation.status is UpdateStatus.REFUSED and "held" in innovation.message
    assert nav.state.scale == pytest.approx(3.0)


@pytest.mark.parametrize("scale, sigma", [(math.nan, 0.02), (-1.0, 0.02), (3.0, 0.0)])
def test_a_refined_scale_that_is_not_a_number_is_refused(scale, sigma):
    nav = _anchored_filter(scale=3.0, scale_sigma=0.1)
    assert nav.update(RefinedScale(0.0, scale, sigma, T_BODY_CAM)).status is UpdateStatus.REFUSED
    assert nav.state.scale == pytest.approx(3.0)


def test_the_refinement_recovers_the_scale_from_a_wrong_seed_on_its_schedule():
    imu = SLOW.imu(imu_times(8.0), GYRO_BIAS, ACCEL_BIAS)
    frames = keyframes(SLOW, np.arange(0.0, 8.0001, 0.1))
    refinement = ScaleRefinement(T_BODY_CAM, NavigationSettings(), started_at=1.0, keyframes=frames[:11], imu=imu[:201], recent=frames[:11])
    for sample in imu[201:]:
        refinement.add_imu(sample)
    seed = NavState(1.0, np.zeros(3), np.zeros(3), np.eye(3), gyro_bias=GYRO_BIAS, log_scale=math.log(0.7 * MAP_SCALE), R_world_map=R_WORLD_MAP)
    due = []
    for t, T in frames[11:]:
        refinement.add_pose(t, T)
        if refinement.due(t):
            due.append(t)
            refined = refinement.refine(seed)
    assert due == pytest.approx([1.0 + s for s in REFINE_AFTER_S if s <= 7.0])
    assert refined.measurement is not None, refined.reason
    assert refined.measurement.scale == pytest.approx(MAP_SCALE, rel=0.01)
    assert 0 < refined.measurement.sigma < 0.02


def test_a_start_off_by_the_bias_it_neglected_is_corrected_within_seconds():
    """The linear alignment (here told to allow for no accelerometer bias) starts the filter 16 %
    off on a slow motion; the refinements 2.5 and 5 s after take it to within 1 %, where the
    filter alone is still 8 % off after 6 s."""
    times = np.arange(0.0, 10.0, 1.0 / FRAME_RATE)
    rng = np.random.default_rng(0)
    estimates = []
    for t in times:
        T = map_pose(SLOW, t)
        T[:3, 3] += rng.normal(0.0, 0.003 / MAP_SCALE, 3)  # SLAM's millimetres of noise
        estimates.append(PoseEstimate(float(t), T, TrackingState.OK, 80))
    imu = SLOW.imu(imu_times(10.0), GYRO_BIAS, ACCEL_BIAS)
    settings = NavigationSettings(vi_init_accel_bias_sigma=0.0, vi_init_refine=False)
    errors = {}
    for refine in (False, True):
        stage, _ = _run(estimates, imu, settings=settings.model_copy(update={"refine_scale_after_start": refine}))
        assert abs(stage.alignment.scale / MAP_SCALE - 1.0) > 0.1  # the start
        errors[refine] = abs(stage.records[-1].output.scale / MAP_SCALE - 1.0)
        refinements = [n.text for n in stage.notices if n.code == "scale_refinement"]
        assert bool(refinements) == refine
    assert errors[True] < 0.01 < 0.05 < errors[False]
    assert any("accepted" in text for text in refinements)


def test_where_the_map_s_scale_changed_over_its_keyframes_the_newer_half_is_refined():
    """A downward camera climbing changes SLAM's map scale as it goes; one scale fitted to all
    the keyframes is then none of them, however small its sigma: the newer half disagrees, and
    its scale is the answer; the older keyframes are left out from then on."""
    imu = SLOW.imu(imu_times(8.0), GYRO_BIAS, ACCEL_BIAS)
    frames = []
    for t, T in keyframes(SLOW, np.arange(0.0, 8.0001, 0.1)):
        T = T.copy()
        T[:3, 3] /= 1.0 + 0.03 * t  # the map's metres per unit grow 3 % a second
        frames.append((t, T))
    refinement = ScaleRefinement(T_BODY_CAM, NavigationSettings(), started_at=1.0, keyframes=frames[:11], imu=imu, recent=frames[:11])
    seed = NavState(1.0, np.zeros(3), np.zeros(3), np.eye(3), gyro_bias=GYRO_BIAS, log_scale=math.log(MAP_SCALE), R_world_map=R_WORLD_MAP)
    outcomes = []
    for t, T in frames[11:]:
        refinement.add_pose(t, T)
        if refinement.due(t):
            outcomes.append(refinement.refine(seed))
    changed = next(o for o in outcomes if "scale changed" in o.reason)
    first, last = changed.reason.split("from ")[1].split(" s")[0], changed.timestamp
    newer_scale = MAP_SCALE * (1.0 + 0.03 * 0.5 * (float(first) + last))  # the newer half's mean
    assert changed.measurement.scale == pytest.approx(newer_scale, rel=0.02)
    assert refinement.span_start >= float(first)


def test_a_jump_of_the_map_ends_the_refinements():
    """A loop correction moves SLAM's poses (here 3 m, unannounced): the keyframes kept before it
    are placed as the map was, and a refinement across them would be garbage."""
    trajectory = SinusoidTrajectory()
    times = np.arange(0.0, 6.0, 1.0 / FRAME_RATE)
    moved = {"t_world_map": T_WORLD_MAP + [3.0, 0.0, 0.0]}
    estimates = [PoseEstimate(float(t), map_pose(trajectory, t, **(moved if t >= 2.5 else {})), TrackingState.OK) for t in times]
    settings = NavigationSettings(vi_init_accel_bias_sigma=0.0, visual_jump_reset_s=0.5)
    stage, _ = _run(estimates, trajectory.imu(imu_times(6.0)), settings=settings)
    refinements = [n.timestamp for n in stage.notices if n.code == "scale_refinement"]
    assert refinements and max(refinements) < 2.5 and stage.scale_refinement is None
    assert abs(stage.records[-1].output.scale / MAP_SCALE - 1.0) < 0.01
