"""The navigation filter on a trajectory known in closed form (tests/fusion/inertial_trajectory.py)."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from scipy.stats import chi2

from evp.config import NavigationSettings
from evp.fusion.innovation import UpdateStatus
from evp.fusion.measurements import BaroAltitude, BeaconDistance, GpsPosition, MarkerPose, RangeHeight, Refusal, VisualPose, WheelSpeed, YawRate
from evp.fusion.nav_state import BARO_BIAS, ERROR_DIM, NavState, so3_log
from evp.fusion.navigation_filter import NavigationFilter
from evp.types import ImuSample
from tests.fusion.inertial_trajectory import SinusoidTrajectory, imu_times

RATE = 200.0
TRUE_GYRO_BIAS = np.array([0.003, -0.002, 0.004])
TRUE_ACCEL_BIAS = np.array([0.1, -0.15, 0.08])
R_WORLD_MAP = Rotation.from_euler("xyz", [0.3, -0.2, 1.0]).as_matrix()
T_WORLD_MAP = np.array([5.0, -3.0, 2.0])
MAP_SCALE = 4.0  # metres per map unit: the map is the world scaled by 0.25
T_BODY_CAM = np.eye(4)
T_BODY_CAM[:3, :3] = Rotation.from_euler("xyz", [-np.pi / 2, 0, -np.pi / 2]).as_matrix()  # camera looking along body x
T_BODY_CAM[:3, 3] = [0.05, 0.02, -0.01]


def noisy_imu(trajectory, duration_s, settings, seed=1):
    sqrt_rate = np.sqrt(RATE)
    return trajectory.imu(
        imu_times(duration_s, RATE), TRUE_GYRO_BIAS, TRUE_ACCEL_BIAS, settings.gyro_noise_density * sqrt_rate, settings.accel_noise_density * sqrt_rate, seed
    )


def gps_fix(trajectory, t, rng, sigma=0.3, offset=(0.0, 0.0, 0.0), correlated=(0.0, 0.0, 0.0)):
    """A fix reporting ``sigma`` per axis (the horizontal accuracy is both axes' RMS): white noise
    of the filter's share of its variance, the receiver's ``correlated`` error (see
    :func:`gauss_markov`) and a spoofer's ``offset``."""
    white = sigma * np.sqrt(NavigationSettings().gps_white_share)
    z = trajectory.position(t) + white * rng.standard_normal(3) + np.asarray(offset) + np.asarray(correlated)
    return GpsPosition(t, tuple(z), sigma * np.sqrt(2.0), sigma)


def gauss_markov(times, accuracy, settings, rng):
    """(N, 3) a receiver's correlated errors at ``times``: first-order Gauss-Markov, the settings'
    correlation time, the share of the per-axis ``accuracy``'s variance that is not white."""
    sigma = accuracy * np.sqrt(1.0 - settings.gps_white_share)
    errors, state = [], sigma * rng.standard_normal(3)
    for i, t in enumerate(times):
        if i:
            decay = np.exp(-(t - times[i - 1]) / settings.gps_correlation_time_s)
            state = decay * state + sigma * np.sqrt(1.0 - decay**2) * rng.standard_normal(3)
        errors.append(state)
    return np.array(errors)


def visual_pose(trajectory, t, rng, R_world_map=R_WORLD_MAP, t_world_map=T_WORLD_MAP, position_sigma=0.02, attitude_sigma=0.01):
    T_world_cam = trajectory.pose(t) @ T_BODY_CAM
    T = np.eye(4)
    T[:3, :3] = R_world_map.T @ T_world_cam[:3, :3] @ Rotation.from_rotvec(attitude_sigma * rng.standard_normal(3)).as_matrix()
    T[:3, 3] = R_world_map.T @ (T_world_cam[:3, 3] + position_sigma * rng.standard_normal(3) - t_world_map) / MAP_SCALE
    return VisualPose(t, T, T_BODY_CAM)


def attitude_error(state, trajectory):
    return so3_log(state.R_world_body.T @ trajectory.rotation(state.timestamp))


def test_propagation_alone_reproduces_the_trajectory():
    trajectory = SinusoidTrajectory()
    nav = NavigationFilter(trajectory.state(0.0))
    for sample in trajectory.imu(imu_times(20.0, RATE)):
        assert nav.propagate(sample) is None
    x = nav.state
    assert x.timestamp == 20.0
    assert np.linalg.norm(x.position - trajectory.position(20.0)) < 2e-3  # 66 m travelled
    assert np.linalg.norm(x.velocity - trajectory.velocity(20.0)) < 2e-4
    assert np.linalg.norm(attitude_error(x, trajectory)) < 1e-5


def run_with_gps(duration_s=40.0, pull_off_from=None, settings=None):
    """Noisy, biased IMU and 5 Hz GPS (0.3 m, correlated over a minute); from ``pull_off_from`` the GPS is dragged off at 5 m/s."""
    settings = settings or NavigationSettings(initial_yaw_sigma_rad=0.05)
    trajectory = SinusoidTrajectory()
    rng = np.random.default_rng(2)
    nav = NavigationFilter(trajectory.state(0.0), settings)
    nees, innovations = [], []
    imu = noisy_imu(trajectory, duration_s, settings)
    correlated = iter(gauss_markov([s.timestamp for s in imu[40::40]], 0.3, settings, rng))
    for k, sample in enumerate(imu):
        nav.propagate(sample)
        if k % 40 == 0 and k > 0:
            t = sample.timestamp
            offset = (0.0, 0.0, 0.0) if pull_off_from is None or t < pull_off_from else (5.0 * (t - pull_off_from), 0.0, 0.0)
            innovations.append(nav.update(gps_fix(trajectory, t, rng, offset=offset, correlated=next(correlated))))
        if k % 20 == 0:
            x = nav.state
            error = np.concatenate(
                [trajectory.position(x.timestamp) - x.position, trajectory.velocity(x.timestamp) - x.velocity, attitude_error(x, trajectory)]
            )
            nees.append(error @ np.linalg.solve(nav.covariance[:9, :9], error))
    return trajectory, nav, np.array(nees), innovations


def test_imu_and_gps_stay_within_their_covariance_and_recover_the_biases():
    trajectory, nav, nees, innovations = run_with_gps()
    assert all(i.accepted for i in innovations)
    # normalised estimation error squared of position, velocity and attitude (9 dof)
    assert np.mean(nees) < 9 * 1.5
    assert np.mean(nees > chi2.ppf(0.997, 9)) < 0.01  # the 3-sigma bound, jointly
    x, sigma = nav.state, np.sqrt(np.diag(nav.covariance))
    assert np.all(np.abs(x.gyro_bias - TRUE_GYRO_BIAS) < 3 * sigma[9:12])
    assert np.all(np.abs(x.accel_bias - TRUE_ACCEL_BIAS) < 3 * sigma[12:15])
    assert np.linalg.norm(x.gyro_bias - TRUE_GYRO_BIAS) < 1e-3
    assert np.linalg.norm(x.accel_bias - TRUE_ACCEL_BIAS) < 0.06
    assert nav.output().georeferenced


def test_gps_pulled_off_at_5_m_s_is_rejected_by_the_gate():
    """The filter's own guard; whether GPS is trusted at all is the GpsMonitor's call upstream.
    The first 0.4 s of the ramp (up to 2 m off, within the gate) do enter and bend the velocity,
    which then drifts the coasting estimate: a per-fix gate cannot tell a slow ramp from noise."""
    trajectory, nav, _, innovations = run_with_gps(duration_s=30.0, pull_off_from=20.0)
    spoofed = [i for i in innovations if i.timestamp >= 20.5]
    assert spoofed and all(i.status is UpdateStatus.GATED for i in spoofed)
    assert "gate" in spoofed[0].message
    assert np.linalg.norm(nav.state.position - trajectory.position(30.0)) < 10.0  # GPS ends 50 m off


def test_visual_poses_recover_the_map_scale_and_pose():
    settings = NavigationSettings(initial_yaw_sigma_rad=0.05, initial_log_scale_sigma=0.3)
    trajectory = SinusoidTrajectory()
    rng = np.random.default_rng(3)
    nav = NavigationFilter(trajectory.state(0.0, log_scale=np.log(3.0)), settings)  # scale 25 % off
    for k, sample in enumerate(noisy_imu(trajectory, 20.0, settings)):
        nav.propagate(sample)
        if k % 10 == 0:
            assert nav.update(visual_pose(trajectory, sample.timestamp, rng)).accepted
    x = nav.state
    assert abs(x.scale / MAP_SCALE - 1.0) < 0.01
    # the map's tilt is observable through gravity: recovered in the world
    tilt = so3_log(R_WORLD_MAP @ x.R_world_map.T)[:2]
    assert np.degrees(np.linalg.norm(tilt)) < 0.5
    # heading and position are not (no GPS): the map's pose is recovered relative to the body
    true_body = trajectory.pose(20.0)
    assert np.degrees(np.linalg.norm(so3_log((x.R_world_body.T @ x.R_world_map).T @ true_body[:3, :3].T @ R_WORLD_MAP))) < 0.5
    map_from_body = x.R_world_body.T @ (x.t_world_map - x.position)
    assert np.linalg.norm(map_from_body - true_body[:3, :3].T @ (T_WORLD_MAP - true_body[:3, 3])) < 0.3
    out = nav.output(T_BODY_CAM)
    assert out.scale_known and not out.georeferenced
    assert np.allclose(out.T_world_cam, out.T_world_body @ T_BODY_CAM)
    assert out.covariance.shape == (6, 6) and np.all(np.linalg.eigvalsh(out.covariance) > 0)


def test_a_far_scene_s_poses_are_weighed_by_its_depth():
    """Poses tracked on a scene 30 m away err by decimetres (0.5 % of the depth here): told the
    depth, the filter weighs them so and recovers the scale; held to visual_position_sigma_m
    (2 cm) it finds them inconsistent and refuses many."""
    depth_m, settings = 30.0, NavigationSettings(initial_yaw_sigma_rad=0.05, initial_log_scale_sigma=0.3)
    sigma_m = settings.visual_position_sigma_per_depth * depth_m
    assert sigma_m > 5 * settings.visual_position_sigma_m
    trajectory = SinusoidTrajectory()
    outcomes = {}
    for told in (True, False):
        rng = np.random.default_rng(3)
        nav = NavigationFilter(trajectory.state(0.0, log_scale=np.log(3.0)), settings)  # scale 25 % off
        statuses = []
        for k, sample in enumerate(noisy_imu(trajectory, 20.0, settings)):
            nav.propagate(sample)
            if k % 10 == 0:
                pose = visual_pose(trajectory, sample.timestamp, rng, position_sigma=sigma_m)
                if told:
                    pose = VisualPose(pose.timestamp, pose.T_map_cam, pose.T_body_cam, depth=depth_m / MAP_SCALE)
                statuses.append(nav.update(pose).status)
        outcomes[told] = (np.mean([status is UpdateStatus.GATED for status in statuses]), nav.state.scale)
    gated, scale = outcomes[True]
    assert gated < 0.005 and abs(scale / MAP_SCALE - 1.0) < 0.02
    assert outcomes[False][0] > 0.05


def test_a_new_visual_map_is_a_jump_not_motion():
    """After a relocalisation into a map moved by 3 m and 90 degrees, the poses are accepted
    once the filter is told, and the body estimate does not jump."""
    settings = NavigationSettings(initial_yaw_sigma_rad=0.05, initial_log_scale_sigma=0.01)
    trajectory = SinusoidTrajectory()
    rng = np.random.default_rng(4)
    nav = NavigationFilter(trajectory.state(0.0, log_scale=np.log(MAP_SCALE)), settings)
    moved = (Rotation.from_rotvec([0, 0, np.pi / 2]).as_matrix() @ R_WORLD_MAP, T_WORLD_MAP + [3.0, 0.0, 0.0])
    for k, sample in enumerate(noisy_imu(trajectory, 10.0, settings)):
        nav.propagate(sample)
        if k % 10 == 0:
            t = sample.timestamp
            if t < 5.0:
                assert nav.update(visual_pose(trajectory, t, rng)).accepted
            else:
                if k == 1000:
                    assert nav.update(visual_pose(trajectory, t, rng, *moved)).status is UpdateStatus.GATED  # not yet told
                    assert nav.reset_visual_map(t, keep_scale=True)
                assert nav.update(visual_pose(trajectory, t, rng, *moved)).accepted
    assert np.linalg.norm(nav.state.position - trajectory.position(10.0)) < 0.1
    assert np.linalg.norm(nav.state.t_world_map - moved[1]) < 0.2


def test_barometer_bias_is_estimated_with_gps():
    settings = NavigationSettings(initial_yaw_sigma_rad=0.05, initial_position_sigma_m=3.0)
    trajectory = SinusoidTrajectory()
    rng = np.random.default_rng(5)
    start = trajectory.state(0.0)
    nav = NavigationFilter(NavState(0.0, start.position + [0.0, 0.0, 3.0], start.velocity, start.R_world_body), settings)  # 3 m too high
    bias = 12.0
    for k, sample in enumerate(noisy_imu(trajectory, 20.0, settings)):
        nav.propagate(sample)
        t = sample.timestamp
        if k % 20 == 0:
            assert nav.update(BaroAltitude(t, trajectory.position(t)[2] + bias + 0.3 * rng.standard_normal(), 0.3)).accepted
        if k % 40 == 0 and k > 0:
            assert nav.update(gps_fix(trajectory, t, rng)).accepted
    assert abs(nav.state.baro_bias - bias) < 0.2
    assert abs(nav.output().baro_bias - bias) < 3 * np.sqrt(nav.covariance[BARO_BIAS, BARO_BIAS]) + 0.05


def test_a_late_gps_fix_gives_the_result_of_fusing_it_in_order():
    settings = NavigationSettings(initial_yaw_sigma_rad=0.05)
    trajectory = SinusoidTrajectory()
    imu = noisy_imu(trajectory, 6.0, settings)
    fixes = {k: gps_fix(trajectory, imu[k].timestamp, np.random.default_rng(k)) for k in range(40, len(imu), 40)}
    late = 600  # this fix arrives 0.3 s (60 samples) after its stamp
    in_order, delayed = NavigationFilter(trajectory.state(0.0), settings), NavigationFilter(trajectory.state(0.0), settings)
    for k, sample in enumerate(imu):
        in_order.propagate(sample)
        delayed.propagate(sample)
        if k in fixes:
            in_order.update(fixes[k])
            if k != late:
                delayed.update(fixes[k])
        if k == late + 60:
            assert delayed.update(fixes[late]).accepted
    assert np.allclose(delayed.state.position, in_order.state.position, atol=1e-9)
    assert np.allclose(delayed.covariance, in_order.covariance, atol=1e-12)
    old = gps_fix(trajectory, 0.5, np.random.default_rng(0))
    assert delayed.update(old).status is UpdateStatus.TOO_OLD  # beyond the 1 s horizon


def test_bad_input_is_reported_and_the_filter_keeps_running():
    trajectory = SinusoidTrajectory()
    nav = NavigationFilter(trajectory.state(0.0))
    assert nav.update(gps_fix(trajectory, 0.0, np.random.default_rng(0))).status is UpdateStatus.NO_IMU
    imu = trajectory.imu(imu_times(2.0, RATE))
    for sample in imu[:100]:
        nav.propagate(sample)
    assert nav.propagate(ImuSample(0.6, (np.nan, 0.0, 0.0), (0.0, 0.0, 9.8))).kind == "imu_not_finite"
    assert nav.propagate(imu[50]).kind == "imu_out_of_order"
    assert nav.propagate(imu[99]).kind == "imu_out_of_order"  # a repeated stamp
    assert nav.propagate(imu[140]).kind == "imu_gap"  # 0.2 s without samples
    for sample in imu[141:]:
        assert nav.propagate(sample) is None
    assert nav.state.timestamp == imu[-1].timestamp
    assert np.linalg.norm(nav.state.position - trajectory.position(2.0)) < 0.05  # the gap was bridged
    refused = nav.update(GpsPosition(2.0, (np.nan, np.nan, np.nan)))
    assert refused.status is UpdateStatus.REFUSED and "not finite" in refused.message
    assert nav.update(RangeHeight(2.0, np.nan)).status is UpdateStatus.REFUSED
    assert np.all(np.isfinite(nav.covariance))


def test_a_tilted_range_finder_is_refused_and_a_level_one_is_fused():
    level = NavState(1.0, np.array([0.0, 0.0, 2.0]), np.zeros(3), np.eye(3))
    nav = NavigationFilter(level)
    nav.propagate(ImuSample(1.0, (0.0, 0.0, 0.0), (0.0, 0.0, 9.80665)))
    assert nav.update(RangeHeight(1.0, 2.05, ground_height_m=0.1)).accepted
    tilted = NavigationFilter(NavState(1.0, np.array([0.0, 0.0, 2.0]), np.zeros(3), Rotation.from_rotvec([0.7, 0, 0]).as_matrix()))
    tilted.propagate(ImuSample(1.0, (0.0, 0.0, 0.0), (0.0, 0.0, 9.80665)))
    refused = tilted.update(RangeHeight(1.0, 2.6))
    assert refused.status is UpdateStatus.REFUSED and "tilted 40 deg" in refused.message


def _random_state(rng):
    return NavState(
        0.0,
        rng.normal(size=3) * 3,
        rng.normal(size=3),
        Rotation.random(random_state=1).as_matrix(),
        rng.normal(size=3) * 0.01,
        rng.normal(size=3) * 0.1,
        0.7,
        Rotation.random(random_state=2).as_matrix(),
        rng.normal(size=3),
        1.5,
        map_anchored=True,
    )


def _visual_pose_of(state):
    """The pose the state predicts, moved a little (the rotation residual's first-order model
    holds near zero)."""
    T = np.eye(4)
    T[:3, :3] = state.R_world_map.T @ state.R_world_body @ T_BODY_CAM[:3, :3] @ Rotation.from_rotvec([1e-4, -2e-4, 1e-4]).as_matrix()
    T[:3, 3] = state.R_world_map.T @ (state.position + state.R_world_body @ T_BODY_CAM[:3, 3] - state.t_world_map) / state.scale + 0.05
    return VisualPose(0.0, T, T_BODY_CAM)


def marker_pose(T_world_cam, t, rng, misplaced_m=0.0, position_sigma=0.01, attitude_sigma=0.02):
    """A marker 0.45 m ahead of the camera (a floor under a downward camera), seen with noise; a
    ``misplaced_m`` copy of it sits that far from where the world has it."""
    T_world_marker = np.eye(4)
    T_world_marker[:3, :3] = Rotation.from_euler("z", rng.uniform(-np.pi, np.pi)).as_matrix()
    T_world_marker[:3, 3] = T_world_cam[:3, :3] @ np.array([0.05, -0.03, 0.45]) + T_world_cam[:3, 3]
    T_cam_marker = np.linalg.inv(T_world_cam) @ T_world_marker
    R_seen = T_cam_marker[:3, :3] @ Rotation.from_rotvec(attitude_sigma * rng.standard_normal(3)).as_matrix()
    t_seen = T_cam_marker[:3, 3] + position_sigma * rng.standard_normal(3)
    T_world_marker[:3, 3] += np.array([misplaced_m, 0.0, 0.0])
    return MarkerPose(t, T_world_marker, R_seen, t_seen, T_BODY_CAM)


def test_marker_fixes_hold_a_biased_imu_to_centimetres_and_refuse_a_misplaced_marker():
    """Markers as absolute landmarks (docs/markers.md): with a 10 Hz fix from markers whose world
    poses are known, the filter holds position and heading on a noisy, biased IMU with a wrong
    initial heading, and a second marker with a mapped id (1 m off) is refused by the gate."""
    settings = NavigationSettings(initial_yaw_sigma_rad=0.2)
    trajectory = SinusoidTrajectory()
    rng = np.random.default_rng(4)
    start = trajectory.state(0.0)
    start = NavState(0.0, start.position, start.velocity, Rotation.from_euler("z", 0.1).as_matrix() @ start.R_world_body)
    nav = NavigationFilter(start, settings)
    innovations, errors = [], []
    for k, sample in enumerate(noisy_imu(trajectory, 20.0, settings)):
        nav.propagate(sample)
        if k % 20 == 0 and k > 0:
            t = sample.timestamp
            innovations.append(nav.update(marker_pose(trajectory.pose(t) @ T_BODY_CAM, t, rng)))
            errors.append(np.linalg.norm(nav.state.position - trajectory.position(t)))
    assert all(i.accepted for i in innovations)
    x = nav.state
    assert np.mean(errors[-50:]) < 0.02 and np.linalg.norm(attitude_error(x, trajectory)) < 0.01
    sigma = np.sqrt(np.diag(nav.covariance))
    assert np.all(np.abs(x.position - trajectory.position(x.timestamp)) < 3 * sigma[:3])
    copy = nav.update(marker_pose(trajectory.pose(x.timestamp) @ T_BODY_CAM, x.timestamp, rng, misplaced_m=1.0))
    assert copy.status is UpdateStatus.GATED


def _marker_pose_of(state):
    """A marker seen where the state predicts the camera, moved a little."""
    T_world_cam = np.eye(4)
    T_world_cam[:3, :3] = state.R_world_body @ T_BODY_CAM[:3, :3] @ Rotation.from_rotvec([1e-4, -2e-4, 1e-4]).as_matrix()
    T_world_cam[:3, 3] = state.position + state.R_world_body @ T_BODY_CAM[:3, 3] + 0.05
    T_world_marker = np.eye(4)
    T_world_marker[:3, :3] = Rotation.from_euler("z", 0.7).as_matrix()
    T_world_marker[:3, 3] = [1.0, 2.0, 0.0]
    T_cam_marker = np.linalg.inv(T_world_cam) @ T_world_marker
    return MarkerPose(0.0, T_world_marker, T_cam_marker[:3, :3], T_cam_marker[:3, 3], T_BODY_CAM)


MEASUREMENTS = [
    _visual_pose_of(_random_state(np.random.default_rng(7))),
    _marker_pose_of(_random_state(np.random.default_rng(7))),
    BaroAltitude(0.0, 3.0),
    RangeHeight(0.0, 4.0, ground_height_m=-1.0, offset_body=(0.1, 0.0, -0.2)),
    GpsPosition(0.0, (1.0, 2.0, 3.0), 1.0, 1.0, velocity_enu=(0.5, 0.0, 0.0), antenna_body=(0.1, 0.2, 0.3)),
    WheelSpeed(0.0, 2.0, Rotation.from_rotvec([0.0, 0.1, 0.2]).as_matrix()),
    YawRate(0.0, 0.3),
    BeaconDistance(0.0, (10.0, 5.0, 1.0), 12.0, 0.2, (0.1, 0.0, 0.05)),
]


@pytest.mark.parametrize("measurement", MEASUREMENTS, ids=lambda m: m.kind)
def test_measurement_jacobians_match_finite_differences(measurement):
    rng = np.random.default_rng(7)
    state = _random_state(rng)
    if isinstance(measurement, RangeHeight):
        state = NavState(0.0, np.array([0.0, 0.0, 3.0]), np.zeros(3), Rotation.from_rotvec([0.2, -0.1, 0.5]).as_matrix(), map_anchored=True)
    settings, gyro = NavigationSettings(), np.array([0.1, -0.2, 0.3])
    lin = measurement.linearise(state, gyro, settings)
    assert not isinstance(lin, Refusal)
    numeric = np.zeros_like(lin.jacobian)
    eps = 1e-6
    for i in range(ERROR_DIM):
        dx = np.zeros(ERROR_DIM)
        dx[i] = eps
        plus, minus = measurement.linearise(state.inject(dx), gyro, settings), measurement.linearise(state.inject(-dx), gyro, settings)
        numeric[:, i] = (minus.residual - plus.residual) / (2 * eps)  # residual = z - h(x)
    assert np.allclose(lin.jacobian, numeric, atol=2e-4 * max(1.0, np.abs(numeric).max()))
