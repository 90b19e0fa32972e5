"""The navigation filter's nominal state and the layout of its error state.

Frames: the world is gravity-aligned ENU (z up; ENU at the take-off point once georeferenced);
the body is the IMU frame; the visual map is the SLAM map's own frame, in its own arbitrary units.
A map point ``x_map`` is ``exp(log_scale) * R_world_map @ x_map + t_world_map`` in the world.

Error state (26 numbers, :data:`ERROR_DIM`), ``true = nominal (+) error``:

- ``dp``, ``dv``: world position and velocity, added;
- ``dtheta``: body attitude, local (``R = R_nominal Exp(dtheta)``), so gravity fixes its body
  x/y components and heading lives in all three;
- ``dbg``, ``dba``: gyro and accelerometer biases, added;
- ``dlog_scale``: the visual map's scale (metres per map unit), as a logarithm so that it stays
  positive and its error is relative;
- ``dtheta_map``, ``dt_map``: the visual map's pose in the world. The rotation is full 3-D and
  its error global (``R_world_map = Exp(dtheta_map) R_nominal``): a monocular map starts in the
  first keyframe's frame, tilted arbitrarily against gravity, so roll and pitch are unknowns as
  much as yaw until the IMU has seen gravity; with a global error its world-z component is the
  heading, the only part that stays unobservable without GPS or another absolute reference;
- ``dbaro``: barometer bias (baro altitude minus world z), added;
- ``dgps``: the GPS receiver's slowly varying position error (fix minus truth, ENU, m), added: a
  first-order Gauss-Markov process (multipath and the atmosphere's delays change over about a
  minute), so that a minute of fixes is not taken for 600 independent ones.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np
from scipy.spatial.transform import Rotation

from evp.geometry.transforms import skew

POSITION = slice(0, 3)
VELOCITY = slice(3, 6)
ATTITUDE = slice(6, 9)
GYRO_BIAS = slice(9, 12)
ACCEL_BIAS = slice(12, 15)
LOG_SCALE = 15
MAP_ATTITUDE = slice(16, 19)
MAP_POSITION = slice(19, 22)
MAP_HORIZONTAL_POSITION = slice(19, 21)  # the map's east and north placement: what nothing but GPS observes
BARO_BIAS = 22
GPS_BIAS = slice(23, 26)
ERROR_DIM = 26
MAP_POSE = np.r_[16:22]  # what a jump in the visual poses (relocalisation, loop closure) leaves unknown
MAP_STATES = np.r_[LOG_SCALE, 16:22]  # what a new visual map leaves unknown: its pose and its scale


def so3_exp(rotation_vector: np.ndarray) -> np.ndarray:
    """Rotation matrix of a rotation vector (Rodrigues). By hand because it runs twice per IMU
    sample: SciPy's ``Rotation.from_rotvec(...).as_matrix()`` takes ~20 us, this ~4 us."""
    x, y, z = rotation_vector
    angle2 = x * x + y * y + z * z
    if angle2 < 1e-16:
        a, b = 1.0, 0.5
    else:
        angle = np.sqrt(angle2)
        a, b = np.sin(angle) / angle, (1.0 - np.cos(angle)) / angle2
    k = np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])
    return np.eye(3) + a * k + b * (k @ k)


def so3_exp_many(rotation_vectors: np.ndarray) -> np.ndarray:
    """:func:`so3_exp` of each row of an (N, 3) array, as one array operation: (N, 3, 3)."""
    v = np.asarray(rotation_vectors, float).reshape(-1, 3)
    angle2 = np.einsum("ni,ni->n", v, v)
    small = angle2 < 1e-16
    angle = np.sqrt(np.where(small, 1.0, angle2))
    a = np.where(small, 1.0, np.sin(angle) / angle)
    b = np.where(small, 0.5, (1.0 - np.cos(angle)) / np.where(small, 1.0, angle2))
    k = skew(v)
    return np.eye(3) + a[:, None, None] * k + b[:, None, None] * (k @ k)


def so3_log(R: np.ndarray) -> np.ndarray:
    """Rotation vector of a rotation matrix (SciPy; robust near pi)."""
    return Rotation.from_matrix(R).as_rotvec()


def skew3(v: np.ndarray) -> np.ndarray:
    """``[v]x`` of one 3-vector (``evp.geometry.transforms.skew`` takes stacks at 4x the cost)."""
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


@dataclass(frozen=True)
class NavState:
    """Nominal state at ``timestamp``. Immutable: every step makes a new one, so the filter's
    history keeps past states without copying."""

    timestamp: float
    position: np.ndarray  # world, m
    velocity: np.ndarray  # world, m/s
    R_world_body: np.ndarray  # 3x3
    gyro_bias: np.ndarray = field(default_factory=lambda: np.zeros(3))  # rad/s
    accel_bias: np.ndarray = field(default_factory=lambda: np.zeros(3))  # m/s^2
    log_scale: float = 0.0  # ln(metres per visual map unit)
    R_world_map: np.ndarray = field(default_factory=lambda: np.eye(3))
    t_world_map: np.ndarray = field(default_factory=lambda: np.zeros(3))
    baro_bias: float = 0.0  # baro altitude minus world z, m
    gps_bias: np.ndarray = field(default_factory=lambda: np.zeros(3))  # GPS fix minus truth, ENU, m
    gps_bias_variance: np.ndarray | None = None  # its stationary variance per axis, from the first fused fix (None before)
    map_anchored: bool = False  # the visual map's pose in the world has been set from a visual pose
    baro_initialised: bool = False  # the barometer bias has been set from a first reading
    georeferenced: bool = False  # a GPS fix has been fused: the world is ENU at its origin

    @property
    def scale(self) -> float:
        """Metres per visual map unit."""
        return float(np.exp(self.log_scale))

    def inject(self, dx: np.ndarray) -> NavState:
        """The nominal state corrected by an error-state estimate ``dx`` (the error is then reset
        to zero; the reset's covariance Jacobian is identity to first order and is not applied,
        as in most ESKF implementations)."""
        return replace(
            self,
            position=self.position + dx[POSITION],
            velocity=self.velocity + dx[VELOCITY],
            R_world_body=self.R_world_body @ so3_exp(dx[ATTITUDE]),
            gyro_bias=self.gyro_bias + dx[GYRO_BIAS],
            accel_bias=self.accel_bias + dx[ACCEL_BIAS],
            log_scale=self.log_scale + float(dx[LOG_SCALE]),
            R_world_map=so3_exp(dx[MAP_ATTITUDE]) @ self.R_world_map,
            t_world_map=self.t_world_map + dx[MAP_POSITION],
            baro_bias=self.baro_bias + float(dx[BARO_BIAS]),
            gps_bias=self.gps_bias + dx[GPS_BIAS],
        )

    @staticmethod
    def levelled(timestamp: float, specific_force_body: np.ndarray, yaw_rad: float = 0.0, position: np.ndarray | None = None) -> NavState:
        """At rest: roll and pitch from the measured specific force (which points up at rest),
        heading ``yaw_rad`` (about world z), zero velocity."""
        up_body = np.asarray(specific_force_body, float) / np.linalg.norm(specific_force_body)
        # the rotation taking the body's measured "up" onto world z, then the heading about z
        tilt, _ = Rotation.align_vectors([[0.0, 0.0, 1.0]], [up_body])
        R = Rotation.from_rotvec([0.0, 0.0, yaw_rad]) * tilt
        return NavState(timestamp, np.zeros(3) if position is None else np.asarray(position, float), np.zeros(3), R.as_matrix())
