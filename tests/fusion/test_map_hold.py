"""The visual map held where GPS placed it while GPS is lost: its scale, attitude and east-north
placement stay whatever the other sensors say (nothing but GPS observes them), its height follows
the barometer."""

import numpy as np

from evp.fusion.innovation import UpdateStatus
from evp.fusion.measurements import BaroAltitude, VisualPose
from evp.fusion.nav_state import ERROR_DIM
from tests.fusion.test_navigation_filter import T_BODY_CAM
from tests.fusion.test_scale_refinement import _anchored_filter


def _seen_from(x, offset_m: np.ndarray) -> VisualPose:
    """The camera pose the map would give with the body ``offset_m`` (world) from the state's."""
    R_map_world = x.R_world_map.T
    camera = x.position + offset_m + x.R_world_body @ T_BODY_CAM[:3, 3]
    T = np.eye(4)
    T[:3, :3] = R_map_world @ x.R_world_body @ T_BODY_CAM[:3, :3]
    T[:3, 3] = R_map_world @ (camera - x.t_world_map) / x.scale
    return VisualPose(0.0, T, T_BODY_CAM)


def test_a_held_map_keeps_scale_attitude_and_east_north_and_the_barometer_moves_its_height():
    for release in (False, True):
        rng = np.random.default_rng(11)
        nav = _anchored_filter(scale=3.0, scale_sigma=0.1, covariance=np.eye(ERROR_DIM) * 1e-2)
        x = nav.state
        B = rng.normal(size=(7, 7)) * 0.03
        nav.hold_map(x.log_scale + 0.02, x.R_world_map, x.t_world_map + [1.0, -2.0, 0.5], B @ B.T + np.eye(7) * 1e-4)  # correlated, as a fit's is
        if release:
            nav.release_map()
        held = nav.state
        assert nav.update(BaroAltitude(0.0, 100.0, 0.3)).status is UpdateStatus.ACCEPTED  # sets the barometer's bias
        for step in range(5):  # the map's poses tie the body to the map's placement, the barometer's step moves both
            assert nav.update(_seen_from(nav.state, np.array([0.02, -0.01, 0.0]))).status is UpdateStatus.ACCEPTED
            assert nav.update(BaroAltitude(0.0, 100.3, 0.3)).status is UpdateStatus.ACCEPTED
        after = nav.state
        assert abs(after.t_world_map[2] - held.t_world_map[2]) > 1e-3  # the height is the barometer's to move
        assert np.all(np.linalg.eigvalsh(nav.covariance) > 0)
        if release:  # free, the correlations carry the steps east and north, and to the scale
            assert np.abs(after.t_world_map[:2] - held.t_world_map[:2]).max() > 1e-3 and after.scale != held.scale
        else:
            assert after.scale == held.scale and np.array_equal(after.R_world_map, held.R_world_map)
            assert np.array_equal(after.t_world_map[:2], held.t_world_map[:2])


def test_the_body_carried_with_a_held_map_errs_as_the_map_does_in_the_world_not_in_the_map():
    """Held off by a fit's metres, the map moves the body in the world with it: the body's world
    position is as uncertain as the fit makes it, and its place in the map (what a visual pose
    tells) is as certain as before whatever the fit's uncertainty, so visual poses keep steering it."""
    predicted, world = [], []
    for fit_sigma in (1e-3, 0.05):
        nav = _anchored_filter(scale=3.0, scale_sigma=0.1)
        x = nav.state
        nav.hold_map(x.log_scale + 0.02, x.R_world_map, x.t_world_map + [1.0, -2.0, 0.5], np.eye(7) * fit_sigma**2)
        lin = _seen_from(nav.state, np.zeros(3)).linearise(nav.state, np.zeros(3), nav.settings)
        predicted.append((lin.jacobian @ nav.covariance @ lin.jacobian.T)[:3, :3])  # the camera's map position
        world.append(np.trace(nav.covariance[0:3, 0:3]))
    assert np.allclose(predicted[0], predicted[1], rtol=0.01)  # the tilt, the IMU's, couples a trace in through the lever
    assert world[1] > world[0] + 3 * 0.05**2  # the placement's variance at least, in all three axes
