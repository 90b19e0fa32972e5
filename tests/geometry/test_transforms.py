"""Rigid-motion helpers."""

import numpy as np
from scipy.spatial.transform import Rotation

from evp.geometry.transforms import scale_motion, se3


def test_scaled_motion_turns_about_the_same_axis_by_the_scaled_angle():
    rotvec = np.radians(3.0) * np.array([0.6, -0.8, 0.0])
    step = se3(Rotation.from_rotvec(rotvec).as_matrix(), np.array([0.1, -0.02, 0.05]))
    tripled = scale_motion(step, 3.0)
    assert np.allclose(Rotation.from_matrix(tripled[:3, :3]).as_rotvec(), 3.0 * rotvec)
    assert np.allclose(tripled[:3, :3], np.linalg.matrix_power(step[:3, :3], 3))
    assert np.allclose(tripled[:3, 3], 3.0 * step[:3, 3])
    assert np.allclose(scale_motion(step, 1.0), step)
    assert np.allclose(scale_motion(step, 0.0), np.eye(4))
    half = scale_motion(step, 0.5)
    assert np.allclose(half[:3, :3] @ half[:3, :3], step[:3, :3])
