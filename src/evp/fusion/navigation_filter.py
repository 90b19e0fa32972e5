"""Error-state extended Kalman filter for a vehicle carrying an IMU (strapdown INS), after
ethzasl_msf (visual scale and the visual map's drift as states) and PX4 EKF2 (delayed horizon,
innovation gates, resets).

The IMU drives the state (:func:`NavigationFilter.propagate`); every other sensor is an update
(:func:`NavigationFilter.update` with a record of :mod:`evp.fusion.measurements`), gated by a
chi-square test on its normalised innovation squared (the filter's own guard; whether GPS is
trusted at all is decided upstream by the seed-002 :class:`~evp.fusion.gps_monitor.GpsMonitor`).

Delayed and out-of-order measurements: the filter keeps a time-ordered history of the last
``history_s`` seconds, one node per IMU sample (the sample, the state and covariance after it,
and the updates fused there). A measurement is fused at the node of the newest IMU sample at or
before its stamp (so its time is rounded down by at most one IMU period: 5 ms at 200 Hz; EuRoC's
camera stamps fall on IMU samples); when that is not the newest node the filter rolls back to it,
fuses, and re-propagates the later IMU samples with their updates, so a late measurement gives
the result it would have given in order. One older than the horizon is refused (``TOO_OLD``).

A new visual map (SLAM reset) or a jump in the visual poses (relocalisation, loop closure) is
told with :meth:`NavigationFilter.reset_visual_map`: the map-to-world pose (and, for a new map,
its scale) is forgotten, the next visual pose re-anchors it (nominal set so that pose agrees with
the current body estimate, covariance reset to the prior, then a normal update restores its
correlation with the body pose), so the jump never enters the body state as motion.

A :class:`~evp.fusion.measurements.RefinedScale` (the inertial refinement over the keyframes
since the map began, made from the IMU the filter has integrated) replaces the filter's scale
rather than being averaged with it: fusing both as independent would count that data twice.
The body moves with the map (its offset from the map's origin and its velocity grow with the
scale), and the other states keep the filter's covariance given the scale.

The map's pose and scale can be set from outside and held (:meth:`NavigationFilter.hold_map`: the
fit of the visual map to GPS when GPS is lost; all but its height): held states are Schmidt-Kalman "consider"
states, their uncertainty kept in the covariance (and so in every other state's) but no update
moving them, until :meth:`NavigationFilter.release_map` or a jump of the visual map.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field, replace

import numpy as np

from evp.config import NavigationSettings
from evp.fusion.innovation import Innovation, UpdateStatus, gated_innovation
from evp.fusion.measurements import BaroAltitude, GpsPosition, Measurement, RefinedScale, Refusal, VisualPose
from evp.fusion.nav_state import (
    ACCEL_BIAS,
    ATTITUDE,
    BARO_BIAS,
    ERROR_DIM,
    GPS_BIAS,
    GYRO_BIAS,
    LOG_SCALE,
    MAP_ATTITUDE,
    MAP_HORIZONTAL_POSITION,
    MAP_POSE,
    MAP_POSITION,
    MAP_STATES,
    POSITION,
    VELOCITY,
    NavState,
    skew3,
    so3_exp,
)
from evp.fusion.strapdown import IMU_DIM, ImuNoise, imu_vectors, strapdown_step
from evp.types import ImuSample


@dataclass(frozen=True)
class FilterWarning:
    """A problem with the IMU stream; kinds: imu_not_finite, imu_out_of_order, imu_gap."""

    timestamp: float
    kind: str
    message: str


@dataclass(frozen=True)
class VisualMapReset:
    """The visual map changed at ``timestamp``: a new map (``keep_scale=False``: its scale is
    unknown again) or the same map corrected (relocalisation, loop closure: scale kept)."""

    timestamp: float
    keep_scale: bool
    kind = "visual_map_reset"


@dataclass(frozen=True)
class NavigationOutput:
    """The filter's answer at ``timestamp``: metric, gravity-aligned (ENU once georeferenced).

    ``covariance`` is 6x6 over the output frame's position and its attitude as a small world-frame
    rotation vector (x, y, z; about the world axes, so the last is the heading), the order of
    :class:`evp.types.PoseEstimate`. ``T_world_cam`` is None unless the camera extrinsic is given.
    """

    timestamp: float
    T_world_body: np.ndarray
    T_world_cam: np.ndarray | None
    velocity: np.ndarray
    covariance: np.ndarray
    scale: float  # metres per visual map unit
    scale_sigma: float  # relative, 1 sigma
    gyro_bias: np.ndarray
    accel_bias: np.ndarray
    baro_bias: float
    scale_known: bool
    georeferenced: bool


_DIAGONAL = np.diag_indices(ERROR_DIM)


@dataclass
class _Node:
    imu: ImuSample
    state: NavState
    covariance: np.ndarray
    events: list = field(default_factory=list)  # accepted measurements and map resets, in order


def _uncorrelated(P: np.ndarray, states: np.ndarray, covariance: np.ndarray) -> np.ndarray:
    """``P`` with ``states`` uncorrelated with the rest and ``covariance`` among themselves."""
    P = P.copy()
    P[states, :] = 0.0
    P[:, states] = 0.0
    P[np.ix_(states, states)] = covariance
    return P


def _carried_by_map(P: np.ndarray, offset: np.ndarray, velocity: np.ndarray) -> np.ndarray:
    """``P`` for a body placed where the map has it, ``offset`` (world, m) from the map's origin
    with ``velocity`` through it: its position errs by the map's placement, position and velocity
    by the map's scale and rotation along them (``p = exp(log_scale) Exp(dtheta) R x + t``),
    besides their own error in the map. Left uncorrelated, a map held off by metres read every
    visual pose as the map's error (its variance never shrinks) and the body went on the IMU's
    dead reckoning (seed 002's flight L: 4 m off where the map put the camera 0.1 m from the
    truth). The body's heading, turned with the map's, is not tied to it: tied, the 300 s flight's
    spoofed half went 1.20 -> 1.59 m (docs/decisions.md)."""
    carry = np.eye(ERROR_DIM)
    carry[POSITION, LOG_SCALE] = offset
    carry[POSITION, MAP_ATTITUDE] = -skew3(offset)
    carry[POSITION, MAP_POSITION] = np.eye(3)
    carry[VELOCITY, LOG_SCALE] = velocity
    carry[VELOCITY, MAP_ATTITUDE] = -skew3(velocity)
    return carry @ P @ carry.T


def initial_covariance(s: NavigationSettings) -> np.ndarray:
    """The prior covariance from the settings' initial sigmas (heading: ``initial_yaw_sigma_rad``
    on the body attitude's component along gravity, which for a levelled start is body z)."""
    sigmas = np.zeros(ERROR_DIM)
    sigmas[POSITION] = s.initial_position_sigma_m
    sigmas[VELOCITY] = s.initial_velocity_sigma_m_s
    sigmas[ATTITUDE] = [s.initial_attitude_sigma_rad, s.initial_attitude_sigma_rad, s.initial_yaw_sigma_rad]
    sigmas[GYRO_BIAS] = s.initial_gyro_bias_sigma
    sigmas[ACCEL_BIAS] = s.initial_accel_bias_sigma
    sigmas[LOG_SCALE] = s.initial_log_scale_sigma
    sigmas[MAP_ATTITUDE] = s.initial_map_attitude_sigma_rad
    sigmas[MAP_POSITION] = s.initial_map_position_sigma_m
    sigmas[BARO_BIAS] = s.initial_baro_bias_sigma_m
    variances = sigmas**2
    variances[GPS_BIAS] = (1.0 - s.gps_white_share) * GpsPosition(0.0, (0.0, 0.0, 0.0)).variances(s)  # until a fix gives its accuracy
    return np.diag(variances)


class NavigationFilter:
    """``propagate(imu)`` per IMU sample, ``update(measurement)`` per other reading,
    ``reset_visual_map(t, keep_scale)`` when the visual map jumps, ``output()`` for the answer."""

    def __init__(self, state: NavState, settings: NavigationSettings | None = None, covariance: np.ndarray | None = None):
        self.settings = settings or NavigationSettings()
        s = self.settings
        self._prior_variances = np.diag(initial_covariance(s))
        self._initial = (state, np.diag(self._prior_variances) if covariance is None else np.array(covariance, float))
        imu_noise = ImuNoise(s.gyro_noise_density, s.accel_noise_density, s.gyro_bias_random_walk, s.accel_bias_random_walk)
        self._noise_per_second = np.zeros(ERROR_DIM)  # process noise variance per second, per error state
        self._noise_per_second[:IMU_DIM] = imu_noise.variances_per_second()
        self._noise_per_second[LOG_SCALE] = s.log_scale_random_walk**2
        self._noise_per_second[MAP_ATTITUDE] = s.map_attitude_random_walk**2
        self._noise_per_second[MAP_POSITION] = s.map_position_random_walk**2
        self._noise_per_second[BARO_BIAS] = s.baro_bias_random_walk**2
        self._history: list[_Node] = []
        self._held = np.zeros(ERROR_DIM, bool)  # consider states: in the covariance, never updated

    # --- state ---------------------------------------------------------------------------------

    @property
    def state(self) -> NavState:
        return self._history[-1].state if self._history else self._initial[0]

    @property
    def covariance(self) -> np.ndarray:
        return self._history[-1].covariance if self._history else self._initial[1]

    def output(self, T_body_cam: np.ndarray | None = None) -> NavigationOutput:
        """The newest state as a pose with its 6x6 covariance (of the camera when ``T_body_cam``
        is given, else of the body)."""
        x, P = self.state, self.covariance
        T_world_body = np.eye(4)
        T_world_body[:3, :3], T_world_body[:3, 3] = x.R_world_body, x.position
        J = np.zeros((6, ERROR_DIM))  # output error (position, world rotation) from the error state
        J[0:3, POSITION] = np.eye(3)
        J[3:6, ATTITUDE] = x.R_world_body
        T_world_cam = None
        if T_body_cam is not None:
            T_world_cam = T_world_body @ T_body_cam
            J[0:3, ATTITUDE] = -x.R_world_body @ skew3(T_body_cam[:3, 3])
        scale_sigma = math.sqrt(P[LOG_SCALE, LOG_SCALE])  # d(log s) is the relative error of s
        return NavigationOutput(
            timestamp=x.timestamp,
            T_world_body=T_world_body,
            T_world_cam=T_world_cam,
            velocity=x.velocity.copy(),
            covariance=J @ P @ J.T,
            scale=x.scale,
            scale_sigma=scale_sigma,
            gyro_bias=x.gyro_bias.copy(),
            accel_bias=x.accel_bias.copy(),
            baro_bias=x.baro_bias,
            scale_known=x.map_anchored and scale_sigma < self.settings.scale_known_sigma,
            georeferenced=x.georeferenced,
        )

    def predicted(self, imu_ahead: Sequence[ImuSample], start: tuple[NavState, ImuSample] | None = None) -> tuple[NavState, ImuSample | None]:
        """The newest state carried through IMU samples the filter has not had yet, mean only
        (PX4's output predictor: the filter stays on a delayed horizon, the answer runs ahead of
        it), with the last sample used; ``start``, a previous answer of this call from the same
        newest state, continues from there. Samples not after the last one, or not finite, are
        skipped. The filter is unchanged."""
        if not self._history:
            return self.state, None
        node = self._history[-1]
        state, previous = start if start is not None else (node.state, node.imu)
        for sample in imu_ahead:
            gyro, accel = imu_vectors(sample)
            if sample.timestamp <= previous.timestamp or not (np.isfinite(gyro).all() and np.isfinite(accel).all()):
                continue
            state, _ = strapdown_step(state, previous, sample, self.settings.gravity_m_s2)
            previous = sample
        return state, previous

    # --- IMU -----------------------------------------------------------------------------------

    def propagate(self, imu: ImuSample) -> FilterWarning | None:
        """Integrate one IMU sample. A sample that cannot be used is dropped with a warning
        (not finite, or not after the previous one); a long gap is integrated with one."""
        gyro, accel = imu_vectors(imu)
        if not (math.isfinite(imu.timestamp) and np.isfinite(gyro).all() and np.isfinite(accel).all()):
            return FilterWarning(imu.timestamp, "imu_not_finite", f"IMU sample at {imu.timestamp} holds NaN or infinite values: dropped")
        if not self._history:
            state, P = self._initial
            self._history.append(_Node(imu, replace(state, timestamp=imu.timestamp), P))
            return None
        previous = self._history[-1]
        dt = imu.timestamp - previous.imu.timestamp
        if dt <= 0:
            return FilterWarning(
                imu.timestamp,
                "imu_out_of_order",
                f"IMU sample at {imu.timestamp:.6f} s is not after the previous one ({previous.imu.timestamp:.6f} s): dropped",
            )
        self._history.append(self._step(previous, imu))
        horizon = imu.timestamp - self.settings.history_s
        drop = 0
        while drop < len(self._history) - 1 and self._history[drop + 1].imu.timestamp <= horizon:
            drop += 1
        del self._history[:drop]
        if dt > self.settings.max_imu_gap_s:
            return FilterWarning(imu.timestamp, "imu_gap", f"{dt:.3f} s without IMU samples before {imu.timestamp:.6f} s: integrated as one step")
        return None

    def _step(self, previous: _Node, imu: ImuSample) -> _Node:
        dt = imu.timestamp - previous.imu.timestamp
        state, phi = strapdown_step(previous.state, previous.imu, imu, self.settings.gravity_m_s2)
        P0 = previous.covariance
        P = np.empty_like(P0)
        P[:IMU_DIM, :IMU_DIM] = phi @ P0[:IMU_DIM, :IMU_DIM] @ phi.T
        P[:IMU_DIM, IMU_DIM:] = phi @ P0[:IMU_DIM, IMU_DIM:]
        P[IMU_DIM:, :IMU_DIM] = P[:IMU_DIM, IMU_DIM:].T
        P[IMU_DIM:, IMU_DIM:] = P0[IMU_DIM:, IMU_DIM:]
        P[_DIAGONAL] += self._noise_per_second * dt
        if state.gps_bias_variance is not None:  # the GPS error decays towards zero, its variance towards the stationary one
            decay = math.exp(-dt / self.settings.gps_correlation_time_s)
            state = replace(state, gps_bias=decay * state.gps_bias)
            P[GPS_BIAS, :] *= decay
            P[:, GPS_BIAS] *= decay
            P[GPS_BIAS, GPS_BIAS] += np.diag(state.gps_bias_variance * (1.0 - decay * decay))
        return _Node(imu, state, P)

    # --- updates -------------------------------------------------------------------------------

    def update(self, measurement: Measurement) -> Innovation:
        """Fuse one measurement at its own time (see the module docstring)."""
        t = measurement.timestamp
        if not self._history:
            return Innovation(t, measurement.kind, UpdateStatus.NO_IMU, message="no IMU sample yet")
        index = self._node_index(t)
        if index is None:
            oldest = self._history[0].imu.timestamp
            return Innovation(
                t,
                measurement.kind,
                UpdateStatus.TOO_OLD,
                message=f"stamp {t:.6f} s is before the delayed horizon ({oldest:.6f} s, history_s {self.settings.history_s} s)",
            )
        node = self._history[index]
        innovation, state, P = self._fuse(node, measurement)
        if innovation.accepted:
            node.state, node.covariance = state, P
            node.events.append(measurement)
            self._replay(index)
        return innovation

    def reset_visual_map(self, timestamp: float, keep_scale: bool) -> bool:
        """The visual map changed at ``timestamp`` (see :class:`VisualMapReset`); False when the
        stamp is outside the history (no IMU yet, or older than the horizon)."""
        index = self._node_index(timestamp) if self._history else None
        if index is None:
            return False
        node = self._history[index]
        reset = VisualMapReset(timestamp, keep_scale)
        self._held[MAP_POSE] = False  # the map's pose is unknown again: the next pose re-anchors it
        if not keep_scale:
            self._held[LOG_SCALE] = False
        node.state, node.covariance = self._forget_map(node.state, node.covariance, reset)
        node.events.append(reset)
        self._replay(index)
        return True

    def hold_map(self, log_scale: float, R_world_map: np.ndarray, t_world_map: np.ndarray, covariance: np.ndarray) -> None:
        """Set the visual map's scale and pose in the world (``covariance``: 7 x 7 over the log
        scale, the map attitude's world-frame error and its translation) in every state of the
        history, apart from the rest but for the body it carries, and hold the scale, attitude and horizontal placement
        there: no update moves them (the height stays free for the barometer) until
        :meth:`release_map` or a jump of the map. Nothing but GPS observes where the map lies
        east and north; left free, the placement moved with the states the covariance ties it to
        (seed 002's flight A: 0.8 m east as the barometer moved its height, docs/decisions.md).
        The body moves with the map, keeping where the map has it: its position by the change of
        the map's placement, its velocity and heading by the change of the map's heading (the
        tilt stays the IMU's: gravity fixes it better than a map fitted to GPS); its position and
        velocity then err as the map does (:func:`_carried_by_map`)."""
        states = np.r_[LOG_SCALE, MAP_ATTITUDE, MAP_POSITION]
        R_new, t_new, s_new = np.array(R_world_map, float), np.array(t_world_map, float), math.exp(log_scale)
        for node in self._history:
            x = node.state
            P = _uncorrelated(node.covariance, states, covariance)
            if x.map_anchored:  # else there is no placement to carry the body by (the next pose anchors the map)
                R_change = R_new @ x.R_world_map.T
                heading = so3_exp(np.array([0.0, 0.0, math.atan2(R_change[1, 0], R_change[0, 0])]))
                in_map = x.R_world_map.T @ (x.position - x.t_world_map) / x.scale
                x = replace(x, position=s_new * R_new @ in_map + t_new, velocity=heading @ x.velocity, R_world_body=heading @ x.R_world_body)
                P = _carried_by_map(P, x.position - t_new, x.velocity)
            node.state = replace(x, log_scale=float(log_scale), R_world_map=R_new, t_world_map=t_new)
            node.covariance = P
        self._held[:] = False
        self._held[np.r_[LOG_SCALE, MAP_ATTITUDE, MAP_HORIZONTAL_POSITION]] = True

    def release_map(self) -> None:
        """Updates move the map's scale, attitude and placement again."""
        self._held[:] = False

    @property
    def map_held(self) -> bool:
        return bool(self._held.any())

    def move_world(
        self,
        R: np.ndarray,
        t: np.ndarray,
        pivot: np.ndarray,
        translation_sigma_m: float | np.ndarray,
        yaw_sigma_rad: float,
        gps_bias_variance: np.ndarray | None = None,
    ) -> None:
        """Re-express every state of the history in a new world, ``x_new = R x + t`` (``R`` a
        heading about z: the world turned to ENU once GPS gave the heading; georeferenced from
        then on), and add the new frame's uncertainty: a translation (``translation_sigma_m`` per
        axis, or one for each) and a heading error about ``pivot`` (new world), each moving the
        body and the visual map together. ``gps_bias_variance`` (per ENU axis), when the new frame
        was fitted to GPS fixes: they share the receiver's correlated error, which moves the frame
        by as much as it moves the fixes, so the GPS error state starts here at that variance,
        tied to the translation (a fix then agrees with the moved position until the error has
        had time to change: only that tells the frame's error from the receiver's)."""
        R, t, pivot = np.asarray(R, float), np.asarray(t, float), np.asarray(pivot, float)
        translation_variance = np.broadcast_to(np.square(np.asarray(translation_sigma_m, float)), (3,))
        rotate = np.eye(ERROR_DIM)
        for block in (POSITION, VELOCITY, MAP_ATTITUDE, MAP_POSITION):  # world-frame errors; the body attitude's is local
            rotate[block, block] = R
        up = np.array([0.0, 0.0, 1.0])
        shift = np.zeros((ERROR_DIM, 3))  # the errors a translation of the new frame makes
        shift[POSITION] = np.eye(3)
        shift[MAP_POSITION] = np.eye(3)
        shift[BARO_BIAS, 2] = -1.0
        shared = shift.copy()  # ... and the receiver's error that made it: the fixes moved with it
        shared[GPS_BIAS] = -np.eye(3)
        for node in self._history:
            x = node.state
            x = replace(
                x,
                position=R @ x.position + t,
                velocity=R @ x.velocity,
                R_world_body=R @ x.R_world_body,
                R_world_map=R @ x.R_world_map,
                t_world_map=R @ x.t_world_map + t,
                baro_bias=x.baro_bias - float(t[2]),
                georeferenced=True,
            )
            yaw = np.zeros(ERROR_DIM)  # the errors a small heading error of the new frame makes
            yaw[POSITION] = np.cross(up, x.position - pivot)
            yaw[VELOCITY] = np.cross(up, x.velocity)
            yaw[ATTITUDE] = x.R_world_body.T @ up
            yaw[MAP_ATTITUDE] = up
            yaw[MAP_POSITION] = np.cross(up, x.t_world_map - pivot)
            P = rotate @ node.covariance @ rotate.T + yaw_sigma_rad**2 * np.outer(yaw, yaw) + shift @ np.diag(translation_variance) @ shift.T
            if gps_bias_variance is not None:
                variance = np.asarray(gps_bias_variance, float)
                P[GPS_BIAS, :] = 0.0
                P[:, GPS_BIAS] = 0.0
                P += shared @ np.diag(variance) @ shared.T
                x = replace(x, gps_bias=np.zeros(3), gps_bias_variance=variance)
            node.state, node.covariance = x, 0.5 * (P + P.T)

    def _node_index(self, t: float) -> int | None:
        """The newest node at or before ``t``; None when ``t`` is before the oldest (or not finite)."""
        if not math.isfinite(t) or t < self._history[0].imu.timestamp:
            return None
        index = len(self._history) - 1
        while self._history[index].imu.timestamp > t:
            index -= 1
        return index

    def _replay(self, index: int) -> None:
        """Re-propagate the nodes after ``index`` from its corrected state, re-applying their events."""
        for i in range(index + 1, len(self._history)):
            node = self._step(self._history[i - 1], self._history[i].imu)
            node.events = self._history[i].events
            for event in node.events:
                if isinstance(event, VisualMapReset):
                    node.state, node.covariance = self._forget_map(node.state, node.covariance, event)
                else:
                    _, node.state, node.covariance = self._fuse(node, event, gate=False)
            self._history[i] = node

    def _forget_map(self, x: NavState, P: np.ndarray, reset: VisualMapReset) -> tuple[NavState, np.ndarray]:
        return replace(x, map_anchored=False), self._to_prior(P, MAP_POSE if reset.keep_scale else MAP_STATES)

    def _to_prior(self, P: np.ndarray, states: np.ndarray) -> np.ndarray:
        """``P`` with ``states`` uncorrelated and at their prior variance."""
        return _uncorrelated(P, states, np.diag(self._prior_variances[states]))

    def _fuse(self, node: _Node, measurement: Measurement, gate: bool = True) -> tuple[Innovation, NavState, np.ndarray]:
        """The innovation of ``measurement`` at ``node`` and, when accepted, the corrected state
        and covariance (Joseph form, symmetrised; a refined scale replaces the filter's)."""
        x, P = node.state, node.covariance
        if isinstance(measurement, VisualPose) and not x.map_anchored:
            x, P = self._anchor_map(x, P, measurement)
        elif isinstance(measurement, BaroAltitude) and not x.baro_initialised and math.isfinite(measurement.altitude_m):
            x = replace(x, baro_bias=measurement.altitude_m - x.position[2], baro_initialised=True)
        elif isinstance(measurement, GpsPosition) and x.gps_bias_variance is None:
            x, P = self._start_gps_error(x, P, measurement)
        if isinstance(measurement, RefinedScale) and self._held[LOG_SCALE]:
            return Innovation(measurement.timestamp, measurement.kind, UpdateStatus.REFUSED, message="the map's scale is held (fitted to GPS)"), x, P
        lin = measurement.linearise(x, imu_vectors(node.imu)[0], self.settings)
        if isinstance(lin, Refusal):
            return Innovation(measurement.timestamp, measurement.kind, UpdateStatus.REFUSED, message=lin.reason), x, P
        H, r = lin.jacobian, lin.residual
        PHt = P @ H.T
        # a refined scale is not vetted by the filter's own scale, which is what it corrects (seed 002's
        # flight F, refined pass: started 22 % off claiming 10 %, the gate refused the refinement that
        # set it right and the filter was lost); the stage takes one only where it is known better
        gate = gate and not isinstance(measurement, RefinedScale)
        innovation, S_inv = gated_innovation(measurement.timestamp, measurement.kind, r, H @ PHt + lin.noise, self.settings.gate_probability, gate)
        if not innovation.accepted:
            return innovation, node.state, node.covariance
        if isinstance(measurement, RefinedScale):
            x, P = self._replace_marginal(x, P, H, r, lin.noise, measurement.carried(x))
            return innovation, x, P
        K = PHt @ S_inv
        K[self._held] = 0.0  # consider states (Schmidt): the Joseph form keeps the covariance right for any gain
        I_KH = np.eye(ERROR_DIM) - K @ H
        P = I_KH @ P @ I_KH.T + K @ lin.noise @ K.T
        P = 0.5 * (P + P.T)
        x = x.inject(K @ r)
        if isinstance(measurement, GpsPosition):
            x = replace(x, georeferenced=True)
        return innovation, x, P

    def _replace_marginal(
        self, x: NavState, P: np.ndarray, H: np.ndarray, r: np.ndarray, noise: np.ndarray, carried: tuple[np.ndarray, np.ndarray, np.ndarray]
    ) -> tuple[NavState, np.ndarray]:
        """The filter's estimate of ``H x`` replaced by the measurement (``r``: measured minus
        predicted, ``noise``: its covariance), for an estimate made from the same data as the
        filter's (the inertial refinement of the scale over the IMU the filter integrated), where
        fusing both as independent would count that data twice and leave the filter's own, worse
        answer a say. The joint becomes the filter's distribution of the rest given ``H x`` times
        the measurement's of ``H x``: every state moves with ``H x`` by its regression on it in
        the filter's covariance, except the states ``carried`` names (indices, their change for
        this step and per unit of ``H x`` at the new value, one column per row of ``H``), which
        move as it says; held states do not move."""
        C = P @ H.T
        regression = np.linalg.solve(H @ C, C.T).T  # each state's change per unit of H x, as the filter has it
        states, step, sensitivity = carried
        moved, spread = regression.copy(), regression.copy()
        moved[states], spread[states] = step, sensitivity
        moved[self._held], spread[self._held] = 0.0, 0.0
        P = P - regression @ C.T + spread @ noise @ spread.T  # given H x, then H x's new spread
        return x.inject(moved @ r), 0.5 * (P + P.T)

    def _start_gps_error(self, x: NavState, P: np.ndarray, fix: GpsPosition) -> tuple[NavState, np.ndarray]:
        """The GPS error state at the first fix: zero, uncorrelated, at the stationary variance of
        the correlated part of this fix's accuracy (a receiver reports one accuracy for a run)."""
        variance = (1.0 - self.settings.gps_white_share) * fix.variances(self.settings)
        P = P.copy()
        P[GPS_BIAS, :] = 0.0
        P[:, GPS_BIAS] = 0.0
        P[GPS_BIAS, GPS_BIAS] = np.diag(variance)
        return replace(x, gps_bias=np.zeros(3), gps_bias_variance=variance), P

    def _anchor_map(self, x: NavState, P: np.ndarray, pose: VisualPose) -> tuple[NavState, np.ndarray]:
        """Set the visual map's world pose so that ``pose`` agrees with the current body estimate;
        its covariance is the prior (no correlation), which the update that follows corrects."""
        R_bc, t_bc = pose.T_body_cam[:3, :3], pose.T_body_cam[:3, 3]
        R_world_map = x.R_world_body @ R_bc @ pose.T_map_cam[:3, :3].T
        t_world_map = x.position + x.R_world_body @ t_bc - x.scale * R_world_map @ pose.T_map_cam[:3, 3]
        if not np.isfinite(R_world_map).all() or not np.isfinite(t_world_map).all():
            return x, P
        return replace(x, R_world_map=R_world_map, t_world_map=t_world_map, map_anchored=True), self._to_prior(P, MAP_POSE)
