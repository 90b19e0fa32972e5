"""A flight started from a saved map's georeference (issue 31): the navigation stage is
georeferenced at SLAM's first relocalisation with no GPS at all, and follows the truth; the
georeference fitted at the end of a georeferenced run recovers the map's similarity to ENU.

The drone-flight scenario's motion without rendering: its camera poses enter the stage in a map
frame of known similarity to the world (as SLAM's relocalised poses in a saved map would), with
exact IMU samples; the world is ENU at the scenario's origin."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from evp.config import NavigationSettings
from evp.fusion.map_georeference import MIN_GEOREFERENCED_KEYFRAMES, MapGeoreference, fit_georeference, georeference_from_run
from evp.fusion.navigation_stage import NavigationStage
from evp.pipeline import run_frames
from evp.sim import sensors
from evp.sim.scenarios import SimOptions, build_scenario
from evp.types import PoseEstimate, TrackingState
from tests.fusion.test_navigation_stage import _Answers, _frames
from tests.fusion.test_navigation_stage_sim import EXACT_IMU

FRAME_RATE = 15.0
MAP_SCALE = 0.4  # metres per map unit
R_WORLD_MAP = Rotation.from_euler("zyx", [130.0, 4.0, -170.0], degrees=True).as_matrix()  # a monocular map's arbitrary frame
T_WORLD_MAP = np.array([12.0, -7.0, 31.0])
RELOCALISED_AT_S = 12.0  # the take-off's climb, where the second flight first recognises the map


def _map_pose(T_world_cam: np.ndarray, position_error: np.ndarray) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = R_WORLD_MAP.T @ T_world_cam[:3, :3]
    T[:3, 3] = R_WORLD_MAP.T @ (T_world_cam[:3, 3] + position_error - T_WORLD_MAP) / MAP_SCALE
    return T


def _georeference(origin, yaw_error_deg: float = 0.0, shift_m: float = 0.0, sigma_m: float = 0.5) -> MapGeoreference:
    R = Rotation.from_euler("z", yaw_error_deg, degrees=True).as_matrix() @ R_WORLD_MAP
    return MapGeoreference(MAP_SCALE, R, T_WORLD_MAP + [shift_m, 0.0, 0.0], origin, sigma_m, sigma_m / 40.0, sigma_m / 40.0, 60, sigma_m)


def _second_flight(georeference_for, position_noise_m: float = 0.1):
    """The stage over a 40 s flight taking off away from the first's origin: SLAM lost (waiting to
    relocalise) until RELOCALISED_AT_S, then relocalised and tracking with ``position_noise_m``."""
    scenario = build_scenario("drone-flight", SimOptions(duration_s=40.0, altitude_m=30.0, area_m=(40.0, 24.0), takeoff_m=(8.0, 5.0)))
    start, end = scenario.motion.start, scenario.motion.end
    times = np.arange(start, end, 1.0 / FRAME_RATE)
    noise = np.random.default_rng(3).normal(0.0, position_noise_m, (len(times), 3))
    estimates, resets, relocalised = [], {}, None
    for k, (t, T_world_cam) in enumerate(zip(times, scenario.camera_poses(times), strict=True)):
        if t - start < RELOCALISED_AT_S:
            estimates.append(PoseEstimate(float(t), np.eye(4), TrackingState.LOST, 0))
            continue
        state = TrackingState.OK
        if relocalised is None:
            relocalised, state, resets[k] = float(t), TrackingState.RELOCALIZED, 1
        estimates.append(PoseEstimate(float(t), _map_pose(T_world_cam, noise[k]), state, 80))
    imu = sensors.simulate_imu(scenario.motion.state(sensors.sample_times(start, end, 200.0)), EXACT_IMU, np.random.default_rng(0)).samples
    estimator = _Answers(estimates, resets)
    settings = NavigationSettings(visual_position_sigma_m=position_noise_m)
    stage = NavigationStage(scenario.T_body_cam, settings, lambda: estimator.reset_counter, map_georeference=georeference_for(scenario.origin))
    result = run_frames(estimator, _frames(times), stages=[stage], telemetry=list(imu))
    truth = {float(t): T[:3, 3] for t, T in zip(times, scenario.camera_poses(times), strict=True)}
    return stage, result, relocalised, truth


def _horizontal_errors(result, truth) -> np.ndarray:
    answered = [e for e in result.estimates if e.georeferenced]
    return np.array([np.linalg.norm(e.T_world_cam[:2, 3] - truth[e.timestamp][:2]) for e in answered])


def test_georeferenced_at_the_first_relocalisation_without_gps():
    stage, result, relocalised, truth = _second_flight(lambda origin: _georeference(origin, yaw_error_deg=0.3, shift_m=0.5))
    first = next(e for e in result.estimates if e.georeferenced)
    assert first.timestamp == relocalised and first.metric  # at once: no alignment phase, no GPS
    assert not any(e.metric for e in result.estimates if e.timestamp < relocalised)
    assert stage.geodetic(first.T_world_cam[:3, 3]) is not None  # answers carry latitude, longitude, altitude
    assert [n.code for n in stage.notices if n.level == "info"] == ["navigation_started", "georeferenced"]
    assert "from the saved map" in next(n.text for n in stage.notices if n.code == "georeferenced")
    assert "saved map" in stage.status and stage.map_georeference is None
    # no fix at all: GPS is unavailable, not trusted (and a first fix would be checked before it is)
    assert stage.gps_state == "unavailable" and not any(e.gps_trusted for e in result.estimates)
    errors = _horizontal_errors(result, truth)
    assert len(errors) > 300
    # the georeference's 0.5 m shift and 0.3 degree turn (0.2 m at 40 m from the map's origin)
    assert errors.mean() < 1.0 and errors.max() < 1.5, (errors.mean(), errors.max())
    assert abs(stage.records[-1].output.scale / MAP_SCALE - 1.0) < 0.01
    assert stage.records[-1].output.scale_known


def test_a_new_map_instead_of_the_saved_one_drops_its_georeference():
    """SLAM gave up on the saved map (a reset that is not a relocalisation, before the filter ran):
    its poses are in a new map, which the saved georeference does not describe."""
    estimator = _Answers([PoseEstimate(0.0, np.eye(4), TrackingState.NOT_INITIALIZED, 0)], {0: 1})
    stage = NavigationStage(np.eye(4), NavigationSettings(), lambda: estimator.reset_counter, map_georeference=_georeference((43.7, 10.4, 4.0)))
    assert stage.enu_frame is not None and stage.gps_state == "off"  # waiting to relocalise: GPS is not used
    run_frames(estimator, _frames([0.0]), stages=[stage])
    assert stage.map_georeference is None and stage.enu_frame is None and stage.gps_state == "off"
    assert [n.code for n in stage.notices] == ["saved_map_abandoned"]


def test_the_georeference_fit_recovers_the_maps_similarity_and_its_doubt():
    rng = np.random.default_rng(5)
    centres = rng.uniform([-100, -60, 10], [100, 60, 12], (80, 3))  # a survey: flat, 200 x 120 map units
    enu = MAP_SCALE * centres @ R_WORLD_MAP.T + T_WORLD_MAP
    fitted = fit_georeference(centres, enu + rng.normal(0, 0.3, enu.shape), (43.7, 10.4, 4.0), min_sigma_m=1.5)
    assert fitted.scale == pytest.approx(MAP_SCALE, rel=2e-3)
    assert np.degrees(Rotation.from_matrix(fitted.R @ R_WORLD_MAP.T).magnitude()) < 0.2
    assert np.abs(fitted.apply(centres) - enu).max() < 0.3
    assert fitted.residual_m == pytest.approx(0.3 * np.sqrt(3), rel=0.2) and fitted.translation_sigma_m == 1.5  # a GPS error is not averaged away
    assert fit_georeference(centres[: MIN_GEOREFERENCED_KEYFRAMES - 1], enu[: MIN_GEOREFERENCED_KEYFRAMES - 1], (0, 0, 0), 1.5) is None
    line = np.column_stack([np.linspace(0, 50, 20), np.zeros(20), np.zeros(20)])
    assert fit_georeference(line, line, (0, 0, 0), 1.5) is None  # one line: the rotation about it is free


def test_only_frames_fused_with_trusted_gps_enter_the_fit():
    centres = np.random.default_rng(6).uniform(-50, 50, (30, 3))
    keyframes = [(float(k), c) for k, c in enumerate(centres)]

    def answer(k: int, trusted: bool, position: np.ndarray) -> PoseEstimate:
        T = np.eye(4)
        T[:3, 3] = position
        return PoseEstimate(float(k), T, TrackingState.OK, 80, metric=True, georeferenced=True, gps_trusted=trusted)

    good = [answer(k, True, MAP_SCALE * R_WORLD_MAP @ c + T_WORLD_MAP) for k, c in enumerate(centres[:20])]
    spoofed = [answer(20 + k, False, np.full(3, 1e3)) for k in range(10)]  # dead reckoning through a spoofing: left out
    fitted = georeference_from_run(keyframes, good + spoofed, (43.7, 10.4, 4.0), 1.5)
    assert fitted.keyframes == 20 and fitted.residual_m < 1e-6
    assert georeference_from_run(keyframes, spoofed, (43.7, 10.4, 4.0), 1.5) is None
