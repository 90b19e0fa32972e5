"""The EKF of seed 001: state, prediction from the wheels and the gyro, bearing updates, WiFi fixes, and the
features' life (initialised in inverse depth, made Euclidean, deleted).

State (SI units; the world is the robot's start: x forward, y left, z up, on the ground):

=============  ===========================================================================
0:3            robot x, y (m) and heading (rad, counter-clockwise)
3              gyro bias (rad/s): measured minus true yaw rate
4:7            camera centre in the robot frame (m): calibrated, refined by the filter
then per       inverse depth ``(a_x, a_y, a_z, azimuth, elevation, rho)`` (6) or Euclidean
feature        ``(X, Y, Z)`` (3), in the order of :attr:`EkfSlamFilter.features`
=============  ===========================================================================

Measurements are undistorted, normalised image coordinates ``(x/z, y/z)`` of a feature in the
camera; seed 001's pixel form is the same up to the intrinsics. The camera's rotation on the robot
is the calibration's; the robot turns about the world's vertical only (the paper's 2-D robot).
A WiFi fix (:meth:`EkfSlamFilter.position_fix`) measures the robot's x, y directly; it needs the
world to be the radio map's, so the start pose is then set in that frame (:meth:`set_start`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from functools import lru_cache

import numpy as np
from scipy.linalg import cholesky, solve_triangular
from scipy.stats import chi2

from evp.config import EkfSlamSettings
from evp.ekf_slam.inverse_depth import EUCLIDEAN_SIZE, INVERSE_DEPTH_SIZE, euclidean, linearity_index, ray_angles, ray_direction, ray_direction_derivatives
from evp.fusion.innovation import Innovation, gated_innovation
from evp.fusion.planar_motion import unicycle_step

X, Y, YAW, BIAS = 0, 1, 2, 3
OFFSET = slice(4, 7)
ROBOT_STATES = 7
POSE_AND_OFFSET = np.array([X, Y, YAW, 4, 5, 6])  # the states a bearing depends on besides its feature's
E_Z = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 0.0]])  # [e_z]x


@lru_cache(maxsize=1024)
def chi2_quantile(probability: float, dof: int) -> float:
    return float(chi2.ppf(probability, dof))


def symmetric(block: np.ndarray) -> np.ndarray:
    """A covariance block made exactly symmetric. The filter keeps P exactly symmetric by
    construction (each change writes a block's rows and their transpose, the update subtracts
    the symmetric W^T W), so no pass over all of P is needed to undo rounding."""
    return 0.5 * (block + block.T)


def principal_submatrix(P: np.ndarray, keep: np.ndarray) -> np.ndarray:
    """``P[ix_(keep, keep)]`` for ascending ``keep``, copied block by block between its runs of
    consecutive indices (a deletion leaves a few): 3x faster than numpy's fancy indexing at 480
    states, where each deletion of a feature used to cost as much as a frame's update."""
    breaks = np.flatnonzero(np.diff(keep) != 1) + 1
    runs = list(zip(np.r_[0, breaks], np.r_[breaks, len(keep)]))
    out = np.empty((len(keep), len(keep)))
    for a0, a1 in runs:
        rows = P[keep[a0] : keep[a1 - 1] + 1]
        for b0, b1 in runs:
            out[a0:a1, b0:b1] = rows[:, keep[b0] : keep[b1 - 1] + 1]
    return out


def yaw_rotation(yaw: float) -> np.ndarray:
    c, s = math.cos(yaw), math.sin(yaw)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


@dataclass
class MapFeature:
    """A feature of the state: where its states start, its kind (6: inverse depth, 3: Euclidean),
    what it looks like (ORB descriptors: when first seen, and when last matched) and its record of
    searches (``attempts``) and matches."""

    id: int
    start: int
    size: int
    first_descriptor: np.ndarray
    descriptor: np.ndarray
    attempts: int = 0
    matches: int = 0
    last_seen: float = 0.0

    @property
    def inverse_depth(self) -> bool:
        return self.size == INVERSE_DEPTH_SIZE


@dataclass(frozen=True)
class Predictions:
    """Where the features should appear: ``z`` (m, 2) normalised coordinates, ``jacobian``
    (m, 2, 12) over ``columns`` (m, 12) state indices (a Euclidean feature's last three are
    padding with zero derivative), ``innovation_covariance`` (m, 2, 2) without the measurement
    noise, and ``in_front`` (m,)."""

    z: np.ndarray
    jacobian: np.ndarray
    columns: np.ndarray
    innovation_covariance: np.ndarray
    in_front: np.ndarray


@dataclass
class UpdateRecord:
    """One update: its time, its normalised innovation squared and its degrees of freedom."""

    timestamp: float
    nis: float
    dof: int


@dataclass
class EkfSlamFilter:
    """The filter; ``R_body_cam``, ``t_body_cam``: the camera's calibrated mounting on the robot;
    ``focal_px``: its focal length, which turns the pixel noise into normalised coordinates."""

    R_body_cam: np.ndarray
    t_body_cam: np.ndarray
    settings: EkfSlamSettings
    focal_px: float
    x: np.ndarray = field(init=False)
    P: np.ndarray = field(init=False)
    features: list[MapFeature] = field(default_factory=list, init=False)
    time: float | None = field(default=None, init=False)
    warnings: list[str] = field(default_factory=list, init=False)
    updates: list[UpdateRecord] = field(default_factory=list, init=False)
    fixes: list[Innovation] = field(default_factory=list, init=False)
    inconsistent: bool = field(default=False, init=False)
    _last_input: tuple[float, float, float] = field(default=(0.0, 0.0, 1.0), init=False)  # speed, yaw rate, noise factor
    _next_id: int = field(default=0, init=False)

    def __post_init__(self) -> None:
        s = self.settings
        self.x = np.zeros(ROBOT_STATES)
        self.x[OFFSET] = self.t_body_cam
        self.P = np.zeros((ROBOT_STATES, ROBOT_STATES))
        self.P[BIAS, BIAS] = s.initial_gyro_bias_sigma_rad_s**2
        self.P[OFFSET, OFFSET] = np.eye(3) * s.camera_offset_sigma_m**2

    def set_start(self, x: float, y: float, yaw: float, position_sigma_m: float = 0.0, yaw_sigma_rad: float = 0.0) -> None:
        """The robot's start pose and its uncertainty (default: the world is the start, exactly)."""
        self.x[[X, Y, YAW]] = x, y, yaw
        self.P[X, X] = self.P[Y, Y] = position_sigma_m**2
        self.P[YAW, YAW] = yaw_sigma_rad**2

    # ---- the camera ----------------------------------------------------------------------------

    def camera_pose(self) -> tuple[np.ndarray, np.ndarray]:
        """``R_world_cam`` and the camera centre in the world."""
        Rz = yaw_rotation(self.x[YAW])
        return Rz @ self.R_body_cam, np.array([self.x[X], self.x[Y], 0.0]) + Rz @ self.x[OFFSET]

    # ---- prediction ----------------------------------------------------------------------------

    def predict(self, timestamp: float, speed_m_s: float, yaw_rate_rad_s: float) -> None:
        """A wheel sample: the mean forward speed and measured yaw rate over the interval since the
        previous sample (the first sample starts the clock). A speed beyond ``max_speed_m_s``
        (an encoder counter's wrap or jump), a non-finite value or a saturated gyro is replaced by
        the last good input with its noise inflated, and a warning says so; a sample older than
        the filter is skipped with a warning."""
        s = self.settings
        if self.time is None:
            self.time = float(timestamp)
            return
        if not math.isfinite(timestamp) or timestamp < self.time:
            self._warn(f"wheel sample at {timestamp!r} s is before the filter's {self.time!r} s: skipped")
            return
        factor = 1.0
        if not (math.isfinite(speed_m_s) and abs(speed_m_s) <= s.max_speed_m_s):
            self._warn(f"wheel speed {speed_m_s!r} m/s at {timestamp:.3f} s is not motion (an encoder jump or wrap): the last good speed is used")
            speed_m_s, factor = self._last_input[0], s.bad_input_sigma_factor
        if not (math.isfinite(yaw_rate_rad_s) and abs(yaw_rate_rad_s) < s.gyro_saturation_rad_s):
            self._warn(f"yaw rate {yaw_rate_rad_s!r} rad/s at {timestamp:.3f} s is saturated or missing: the last good rate is used")
            yaw_rate_rad_s, factor = self._last_input[1], s.bad_input_sigma_factor
        if factor == 1.0:
            self._last_input = (speed_m_s, yaw_rate_rad_s, 1.0)
        self._propagate(timestamp - self.time, speed_m_s, yaw_rate_rad_s, factor)
        self.time = float(timestamp)

    def extrapolate(self, timestamp: float) -> None:
        """Predict up to ``timestamp`` (a frame between wheel samples) with the last input; the
        next wheel sample then covers only the rest of its interval."""
        if self.time is None:
            self.time = float(timestamp)
        elif timestamp > self.time:
            self._propagate(timestamp - self.time, *self._last_input)
            self.time = float(timestamp)

    def _propagate(self, dt: float, speed: float, rate: float, factor: float) -> None:
        s = self.settings
        change, d_yaw, d_inputs = unicycle_step(self.x[YAW], speed * dt, (rate - self.x[BIAS]) * dt)
        self.x[[X, Y, YAW]] += change
        F = np.eye(4)
        F[:3, YAW] += d_yaw
        F[:3, BIAS] = -d_inputs[:, 1] * dt
        G = np.zeros((4, 2))
        G[:3] = d_inputs * dt
        speed_sigma = (s.wheel_speed_sigma_m_s + s.wheel_speed_sigma_fraction * abs(speed)) * factor
        # the input noise is per sample, white: its variance over dt shrinks as samples average
        # (sigma^2 x sample period / dt is not known here, so each interval counts as one sample)
        Q = G @ np.diag([speed_sigma**2, (s.gyro_sigma_rad_s * factor) ** 2]) @ G.T
        Q[BIAS, BIAS] += s.gyro_bias_walk_rad_s_per_sqrt_s**2 * dt
        across = np.array([-math.sin(self.x[YAW]), math.cos(self.x[YAW])])  # sideways slip: the wheels do not see it
        Q[:2, :2] += s.lateral_slip_m_per_sqrt_s**2 * dt * np.outer(across, across)
        block = slice(0, 4)
        rows = F @ self.P[block, :]
        corner = rows[:, block] @ F.T + Q
        self.P[block, :] = rows
        self.P[:, block] = rows.T
        self.P[block, block] = symmetric(corner)

    # ---- bearings ------------------------------------------------------------------------------

    def predict_features(self, features: list[MapFeature]) -> Predictions:
        """Predicted normalised coordinates of ``features`` with their Jacobians."""
        m = len(features)
        Rz = yaw_rotation(self.x[YAW])
        R_cw = self.R_body_cam.T @ Rz.T
        centre = np.array([self.x[X], self.x[Y], 0.0]) + Rz @ self.x[OFFSET]
        lever = Rz @ self.x[OFFSET]
        inverse = np.array([f.inverse_depth for f in features], dtype=bool)
        starts = np.array([f.start for f in features], dtype=int)
        columns = np.empty((m, 12), dtype=int)
        columns[:, :6] = POSE_AND_OFFSET
        columns[:, 6:] = starts[:, None] + np.arange(6)
        columns[~inverse, 9:] = starts[~inverse, None]  # a Euclidean feature's padding: zero derivative
        h_world = np.zeros((m, 3))
        d_feature = np.zeros((m, 3, 6))  # d h_world / d feature states
        rho = np.ones(m)
        if inverse.any():
            v = self.x[columns[inverse, 6:]]
            rho[inverse] = v[:, 5]
            da, de = ray_direction_derivatives(v[:, 3], v[:, 4])
            anchor_offset = v[:, :3] - centre
            h_world[inverse] = v[:, 5:6] * anchor_offset + ray_direction(v[:, 3], v[:, 4])
            d_feature[inverse] = np.concatenate([v[:, 5, None, None] * np.eye(3), da[:, :, None], de[:, :, None], anchor_offset[:, :, None]], axis=2)
        if (~inverse).any():
            h_world[~inverse] = self.x[columns[~inverse, 6:9]] - centre
            d_feature[~inverse, :, :3] = np.eye(3)
        h = h_world @ R_cw.T
        in_front = h[:, 2] > 1e-6
        depth = np.where(in_front, h[:, 2], 1.0)
        z = h[:, :2] / depth[:, None]
        d_proj = np.zeros((m, 2, 3))
        d_proj[:, 0, 0] = d_proj[:, 1, 1] = 1.0 / depth
        d_proj[:, :, 2] = -z / depth[:, None]
        d_h = np.zeros((m, 3, 12))
        d_h[:, :, 0] = -rho[:, None] * R_cw[:, 0]
        d_h[:, :, 1] = -rho[:, None] * R_cw[:, 1]
        d_h[:, :, 2] = -((h_world + rho[:, None] * lever) @ (self.R_body_cam.T @ Rz.T @ E_Z).T)
        d_h[:, :, 3:6] = -rho[:, None, None] * self.R_body_cam.T
        d_h[:, :, 6:] = np.einsum("ab,mbc->mac", R_cw, d_feature)
        jacobian = np.einsum("mab,mbc->mac", d_proj, d_h)
        blocks = self.P[columns[:, :, None], columns[:, None, :]]
        covariance = np.einsum("mab,mbc,mdc->mad", jacobian, blocks, jacobian)
        return Predictions(z, jacobian, columns, covariance, in_front)

    def measurement_variance(self) -> float:
        """Variance of one normalised coordinate: the pixel noise over the focal length."""
        return (self.settings.pixel_sigma / self.focal_px) ** 2

    def update(self, timestamp: float, predictions: Predictions, rows: np.ndarray, measured: np.ndarray) -> float:
        """Fuse the measured normalised coordinates ``measured`` (k, 2) of the predictions' ``rows``
        (k,); returns the update's NIS and watches the filter's consistency."""
        k = len(rows)
        if k == 0:
            return 0.0
        J, cols = predictions.jacobian[rows], predictions.columns[rows]
        # H P (2k, n) from the rows of P a bearing depends on: the pose and offset's, shared by all
        # (one product), and each feature's own (a batch of 2 x 6 by 6 x n); H is zero elsewhere
        HP = J[:, :, :6].reshape(2 * k, 6) @ self.P[POSE_AND_OFFSET]
        HP += np.matmul(J[:, :, 6:], self.P[cols[:, 6:].ravel()].reshape(k, 6, -1)).reshape(2 * k, -1)
        S = np.einsum("rkc,kbc->rkb", HP[:, cols], J).reshape(2 * k, 2 * k) + np.eye(2 * k) * self.measurement_variance()
        innovation = (measured - predictions.z[rows]).reshape(-1)
        try:
            L = cholesky(S, lower=True)
        except np.linalg.LinAlgError:
            self._warn(f"update at {timestamp:.3f} s: innovation covariance not positive definite: skipped")
            return float("nan")
        # with S = L L^T and W = L^-1 H P: x += W^T L^-1 innovation, P -= W^T W. W^T W is one
        # symmetric product (BLAS syrk, half the work of P H^T S^-1 H P, and exactly symmetric:
        # P needs no symmetrising pass over its n^2 entries afterwards)
        W = solve_triangular(L, HP, lower=True, check_finite=False)
        whitened = solve_triangular(L, innovation, lower=True, check_finite=False)
        self.x += W.T @ whitened
        self.P -= W.T @ W
        self._wrap_angles()
        nis = float(whitened @ whitened)
        self._watch(UpdateRecord(timestamp, nis, 2 * k))
        return nis

    def position_fix(self, timestamp: float, position: np.ndarray, sigma_m: float, gate_probability: float) -> Innovation:
        """A weak absolute position of the robot (a WiFi fix: ``position`` (2,) m in the world,
        ``sigma_m`` per axis), fused at the filter's time (a scan is at most one wheel period
        older) when its innovation passes the chi-square gate of ``gate_probability`` (the
        navigation filter's gate, :mod:`evp.fusion.innovation`). Every fix leaves its
        :class:`Innovation` in ``fixes``."""
        H = np.zeros((2, len(self.x)))
        H[0, X] = H[1, Y] = 1.0
        residual = np.asarray(position, float) - self.x[[X, Y]]
        PHt = self.P[:, [X, Y]]
        innovation, S_inv = gated_innovation(timestamp, "wifi", residual, PHt[[X, Y]] + np.eye(2) * sigma_m**2, gate_probability)
        self.fixes.append(innovation)
        if innovation.accepted:
            gain = PHt @ S_inv
            self.x += gain @ residual
            self.P -= gain @ PHt.T
            self.P += self.P.T
            self.P *= 0.5
            self._wrap_angles()
        return innovation

    def _watch(self, record: UpdateRecord) -> None:
        """Innovation consistency: the summed NIS of the last updates against its chi-square bound;
        a warning when it first goes beyond (and again after it came back)."""
        self.updates.append(record)
        window = self.updates[-self.settings.consistency_window_frames :]
        nis, dof = sum(u.nis for u in window), sum(u.dof for u in window)
        bound = chi2_quantile(self.settings.consistency_probability, dof)
        now_inconsistent = nis > bound
        if now_inconsistent and not self.inconsistent:
            self._warn(
                f"innovations inconsistent at {record.timestamp:.3f} s: NIS {nis:.0f} over the last {len(window)} updates, "
                f"bound {bound:.0f} for {dof} degrees of freedom: the filter is overconfident or a match is wrong"
            )
        self.inconsistent = now_inconsistent

    def _wrap_angles(self) -> None:
        angles = np.array([YAW, *(f.start + 3 for f in self.features if f.inverse_depth)])
        for i in angles[np.abs(self.x[angles]) > math.pi]:
            self.x[i] = math.remainder(self.x[i], 2 * math.pi)

    # ---- the features' life --------------------------------------------------------------------

    def add_feature(self, z: np.ndarray, descriptor: np.ndarray, timestamp: float) -> MapFeature:
        """A new inverse-depth feature on the ray of normalised coordinates ``z`` from the camera now."""
        return self.add_features(np.asarray(z, float)[None], [descriptor], timestamp)[0]

    def add_features(self, zs: np.ndarray, descriptors: list[np.ndarray], timestamp: float) -> list[MapFeature]:
        """New inverse-depth features on the rays of normalised coordinates ``zs`` (q, 2) from the
        camera now, added together: P grows once, and their covariances with each other come from
        the same product as with the rest (each depends on the robot pose and camera offset only)."""
        s = self.settings
        Rz = yaw_rotation(self.x[YAW])
        R_wc, centre = self.camera_pose()
        q = len(zs)
        J_used = np.zeros((q, 6, 6))  # d feature / d POSE_AND_OFFSET, the only states it depends on
        J_used[:, 0:3, 0] = [1.0, 0.0, 0.0]
        J_used[:, 0:3, 1] = [0.0, 1.0, 0.0]
        J_used[:, 0:3, 2] = E_Z @ Rz @ self.x[OFFSET]
        J_used[:, 0:3, 3:6] = Rz
        J_used[:, 3, 2] = 1.0  # the ray turns with the robot about the vertical
        noise = np.diag([self.measurement_variance(), self.measurement_variance(), s.initial_inverse_depth_sigma**2])
        values = np.empty((q, 6))
        own = np.zeros((6 * q, 6 * q))  # the measurement's and the depth prior's share, feature by feature
        for i, z in enumerate(zs):
            azimuth, elevation, d_angles = ray_angles(R_wc @ np.array([z[0], z[1], 1.0]))
            J_noise = np.zeros((6, 3))  # d feature / d (z_x, z_y, rho)
            J_noise[3:5, 0:2] = d_angles @ R_wc[:, :2]
            J_noise[5, 2] = 1.0
            own[6 * i : 6 * i + 6, 6 * i : 6 * i + 6] = J_noise @ noise @ J_noise.T
            values[i] = [*centre, azimuth, elevation, s.initial_inverse_depth]
        J = J_used.reshape(6 * q, 6)
        cross = J @ self.P[POSE_AND_OFFSET, :]
        new_block = cross[:, POSE_AND_OFFSET] @ J.T + own
        return self._append(values.ravel(), cross, new_block, descriptors, timestamp)

    def add_feature_state(self, values: np.ndarray, covariance: np.ndarray, descriptor: np.ndarray, timestamp: float) -> MapFeature:
        """A feature given as its inverse-depth states (6,) and their covariance, independent of
        the rest (seed 001's experiment: features surveyed by hand, or guessed, at the start)."""
        return self._append(values, np.zeros((6, len(self.x))), covariance, [descriptor], timestamp)[0]

    def _append(self, values: np.ndarray, cross: np.ndarray, covariance: np.ndarray, descriptors: list[np.ndarray], timestamp: float) -> list[MapFeature]:
        """Inverse-depth features at the end of the state: their values (6q,), their covariance
        with the state before them (6q, n) and their own (6q, 6q)."""
        n, m = len(self.x), len(values)
        self.x = np.concatenate([self.x, values])
        grown = np.empty((n + m, n + m))
        grown[:n, :n] = self.P
        grown[n:, :n] = cross
        grown[:n, n:] = cross.T
        grown[n:, n:] = symmetric(covariance)
        self.P = grown
        added = []
        for k, descriptor in enumerate(descriptors):
            added.append(MapFeature(self._next_id, n + INVERSE_DEPTH_SIZE * k, INVERSE_DEPTH_SIZE, descriptor, descriptor, last_seen=timestamp))
            self._next_id += 1
        self.features += added
        return added

    def make_euclidean(self) -> int:
        """Inverse-depth features whose linearity index is below ``euclidean_linearity`` become
        Euclidean points (3 states instead of 6); returns how many did."""
        _, centre = self.camera_pose()
        candidates = [f for f in self.features if f.inverse_depth]
        if not candidates:
            return 0
        starts = np.array([f.start for f in candidates])
        v = self.x[starts[:, None] + np.arange(6)]
        rho_sigma = np.sqrt(np.maximum(self.P[starts + 5, starts + 5], 0.0))
        index = linearity_index(v, rho_sigma, centre)
        drop = []
        for f, keep in zip(candidates, (v[:, 5] <= 0) | (index >= self.settings.euclidean_linearity)):
            if keep:
                continue
            point, J = euclidean(self.x[f.start : f.start + 6])
            block = slice(f.start, f.start + 6)
            rows = J @ self.P[block, :]
            corner = rows[:, block] @ J.T
            self.P[f.start : f.start + 3, :] = rows
            self.P[:, f.start : f.start + 3] = rows.T
            self.P[f.start : f.start + 3, f.start : f.start + 3] = symmetric(corner)
            self.x[f.start : f.start + 3] = point
            drop.extend(range(f.start + 3, f.start + 6))
            f.size = EUCLIDEAN_SIZE
        if drop:  # the three states each conversion freed, deleted together (one copy of P)
            self._delete_states(np.array(drop))
        return len(drop) // 3

    def remove_features(self, ids: set[int]) -> None:
        """Delete features (their states and covariances) by id."""
        if not ids:
            return
        drop = np.concatenate([np.arange(f.start, f.start + f.size) for f in self.features if f.id in ids])
        self.features = [f for f in self.features if f.id not in ids]
        self._delete_states(drop)

    def _delete_states(self, drop: np.ndarray) -> None:
        """Remove the states ``drop`` (indices before the features' renumbering) from x and P."""
        keep = np.setdiff1d(np.arange(len(self.x)), drop)
        self.x = self.x[keep]
        self.P = principal_submatrix(self.P, keep)
        self._renumber()

    def feature_points(self) -> np.ndarray:
        """(N, 3) world points of the features (an inverse-depth one at its current depth)."""
        points = np.zeros((len(self.features), 3))
        inverse = np.array([f.inverse_depth for f in self.features], dtype=bool)
        starts = np.array([f.start for f in self.features], dtype=int)
        if inverse.any():
            v = self.x[starts[inverse, None] + np.arange(6)]
            points[inverse] = v[:, :3] + ray_direction(v[:, 3], v[:, 4]) / v[:, 5:6]
        if (~inverse).any():
            points[~inverse] = self.x[starts[~inverse, None] + np.arange(3)]
        return points

    def _renumber(self) -> None:
        start = ROBOT_STATES
        for f in self.features:
            f.start = start
            start += f.size

    def _warn(self, text: str) -> None:
        self.warnings.append(text)
