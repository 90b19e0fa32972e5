"""The navigation filter as a pipeline stage: SLAM's poses (arbitrary frame and scale) made
metric and gravity-aligned with the IMU, the barometer and the range finder.

The pipeline gives the stage every telemetry record in time order (:meth:`NavigationStage.observe`,
each before the first frame not older than it) and every estimate (:meth:`NavigationStage.process`),
offline and live alike. Until the visual-inertial initialisation
(:func:`~evp.fusion.visual_inertial_init.initialise_visual_inertial`) finds gravity and the scale
observable, the stage keeps the IMU and one tracked pose per ``vi_init_keyframe_interval_s`` and
passes the estimates on unchanged (``metric`` False: "scale not yet observable", the reason in
:attr:`NavigationStage.status`). Then the :class:`~evp.fusion.navigation_filter.NavigationFilter`
starts from the alignment at that frame, the IMU drives it, each tracked pose is a
:class:`~evp.fusion.measurements.VisualPose` update, and each estimate leaves with the filter's
metric camera pose, its 6x6 covariance and the flags (the estimator's pose kept in
``T_visual_cam``). A change of the estimator's reset counter is a jump of the visual poses, not
motion: a relocalisation keeps the map's scale, a new map (SLAM restarted) forgets it.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np

from evp.config import NavigationSettings
from evp.fusion.measurements import BaroAltitude, RangeHeight, VisualPose, WheelSpeed, YawRate
from evp.fusion.nav_state import ATTITUDE, LOG_SCALE, MAP_ATTITUDE, MAP_POSITION, POSITION, VELOCITY
from evp.fusion.navigation_filter import Innovation, NavigationFilter, NavigationOutput, initial_covariance
from evp.fusion.visual_inertial_init import InertialAlignment, initialise_visual_inertial
from evp.fusion.wheel_init import initialise_from_wheels
from evp.types import BaroSample, Frame, ImuSample, PoseEstimate, RangeSample, TrackingState, WheelOdometry

# 1-sigma uncertainties of the filter's start from a visual-inertial alignment. The world is the
# map's frame levelled, so the position, the map's origin and the heading are known at the start
# by definition (small sigmas keep the covariance well conditioned); VINS-Mono's alignment gives
# gravity to about a degree, velocities to a few cm/s and the scale to a few per cent.
START_POSITION_SIGMA_M = 0.01
START_VELOCITY_SIGMA_M_S = 0.1
START_ATTITUDE_SIGMA_RAD = 0.02
START_LOG_SCALE_SIGMA = 0.1
START_MAP_ATTITUDE_SIGMA_RAD = 0.02
START_MAP_POSITION_SIGMA_M = 0.01


@dataclass(frozen=True)
class NavigationRecord:
    """What the filter said at one frame: its output and the visual update's innovation (None
    when the frame was not tracked)."""

    output: NavigationOutput
    visual: Innovation | None


class NavigationStage:
    """A pipeline stage (``observe`` telemetry, ``process`` estimates); see the module docstring.
    ``reset_counter`` reads the estimator's discontinuity counter (``Estimator.reset_counter``)."""

    def __init__(self, T_body_cam: np.ndarray, settings: NavigationSettings | None = None, reset_counter: Callable[[], int] = lambda: 0):
        self.settings = settings or NavigationSettings()
        self.T_body_cam = np.asarray(T_body_cam, float)
        self._reset_counter = reset_counter
        self._last_reset_count = reset_counter()
        self.filter: NavigationFilter | None = None
        self.alignment: InertialAlignment | None = None  # the initialisation that started the filter
        self.initialised_at: float | None = None
        self.status = "scale not yet observable: no tracked pose yet"
        self.warnings: list[str] = []
        self.records: list[NavigationRecord] = []
        self.sensors_used: set[str] = set()
        self._imu: list[ImuSample] = []  # before the filter starts: the samples the initialisation needs
        self._wheel: list[WheelOdometry] = []  # before the filter starts: the wheel records, for the wheel start
        self._keyframes: list[tuple[float, np.ndarray]] = []
        self._last_imu_stamp = -math.inf
        self._ground_height_m: float | None = None  # the range finder's ground, in world z, from its first reading

    # --- telemetry -----------------------------------------------------------------------------

    def observe(self, record) -> None:
        """One telemetry record; kinds the stage does not fuse are ignored."""
        if isinstance(record, ImuSample):
            self._observe_imu(record)
        elif isinstance(record, WheelOdometry) and self.settings.use_wheels:
            self._observe_wheels(record)
        elif self.filter is None:
            return
        elif isinstance(record, BaroSample) and self.settings.use_baro:
            self._update(BaroAltitude(record.timestamp, record.altitude_m))
        elif isinstance(record, RangeSample) and self.settings.use_range:
            self._observe_range(record)

    def _observe_imu(self, sample: ImuSample) -> None:
        values = (sample.timestamp, *sample.angular_velocity_rad_s, *sample.linear_acceleration_m_s2)
        if not all(math.isfinite(v) for v in values):
            self.warnings.append(f"IMU sample at {sample.timestamp} holds NaN or infinite values: dropped")
            return
        if sample.timestamp <= self._last_imu_stamp:
            self.warnings.append(f"IMU sample at {sample.timestamp:.6f} s is not after the previous one ({self._last_imu_stamp:.6f} s): dropped")
            return
        self._last_imu_stamp = sample.timestamp
        self.sensors_used.add("imu")
        if self.filter is None:
            self._imu.append(sample)
            return
        warning = self.filter.propagate(sample)
        if warning is not None:
            self.warnings.append(warning.message)

    def _observe_range(self, sample: RangeSample) -> None:
        if self._ground_height_m is None:
            if not (math.isfinite(sample.distance_m) and sample.distance_m > 0):
                return
            # the ground under the first reading, straight down the body's -z (RangeHeight's default beam)
            state = self.filter.state
            self._ground_height_m = float(state.position[2] - sample.distance_m * state.R_world_body[2, 2])
        self._update(RangeHeight(sample.timestamp, sample.distance_m, self._ground_height_m))

    def _observe_wheels(self, record: WheelOdometry) -> None:
        """Before the start: kept for :func:`initialise_from_wheels`; then the forward speed with
        the non-holonomic constraint (the constraint alone when the record has no speed) and the
        yaw rate, in the IMU's axes (see :mod:`evp.fusion.wheel_init`)."""
        if self.filter is None:
            self._wheel.append(record)
            return
        self._update(WheelSpeed(record.timestamp, record.forward_speed_m_s))
        if math.isfinite(record.yaw_rate_rad_s):
            self._update(YawRate(record.timestamp, record.yaw_rate_rad_s))

    def _update(self, measurement) -> Innovation:
        innovation = self.filter.update(measurement)
        if innovation.accepted:
            self.sensors_used.add(measurement.kind)
        return innovation

    # --- estimates -----------------------------------------------------------------------------

    def process(self, frame: Frame, estimate: PoseEstimate) -> PoseEstimate:
        """The estimate made metric once the filter runs; unchanged (``metric`` False) before."""
        self._follow_resets(estimate)
        tracked = estimate.tracking_state.tracked
        if self.filter is None:
            if tracked:
                self._collect(estimate)
            if self.filter is None:
                return estimate
        visual = self._update(VisualPose(estimate.timestamp, estimate.T_world_cam, self.T_body_cam)) if tracked else None
        output = self.filter.output(self.T_body_cam)
        self.records.append(NavigationRecord(output, visual))
        return replace(
            estimate,
            T_world_cam=output.T_world_cam,
            covariance=output.covariance,
            metric=True,
            scale_known=output.scale_known,
            georeferenced=output.georeferenced,
            T_visual_cam=estimate.T_world_cam,
        )

    def _follow_resets(self, estimate: PoseEstimate) -> None:
        count = self._reset_counter()
        if count == self._last_reset_count:
            return
        self._last_reset_count = count
        if self.filter is None:
            self._keyframes.clear()  # the poses so far belong to another map (or before a jump)
            return
        keep_scale = estimate.tracking_state is TrackingState.RELOCALIZED
        self.filter.reset_visual_map(estimate.timestamp, keep_scale)

    def _collect(self, estimate: PoseEstimate) -> None:
        """Keep the pose as a keyframe when it is far enough after the last, and try to initialise."""
        if self._keyframes and estimate.timestamp - self._keyframes[-1][0] < self.settings.vi_init_keyframe_interval_s:
            return
        self._keyframes.append((estimate.timestamp, estimate.T_world_cam))
        del self._keyframes[: -self.settings.vi_init_window_keyframes]
        oldest = self._keyframes[0][0]
        keep = next((i for i, s in enumerate(self._imu) if s.timestamp >= oldest), len(self._imu))
        del self._imu[: max(0, keep - 1)]  # one sample at or before the oldest keyframe stays
        keep = next((i for i, w in enumerate(self._wheel) if w.timestamp >= oldest), len(self._wheel))
        del self._wheel[: max(0, keep - 1)]  # likewise one wheel record
        alignment = initialise_visual_inertial(self._keyframes, self._imu, self.T_body_cam, self.settings)
        if not alignment.observable and self._wheel:
            wheels = initialise_from_wheels(self._keyframes, self._wheel, self._imu, self.T_body_cam, self.settings)
            if wheels.observable:
                self._start(wheels, "wheel odometry")
                return
            alignment = replace(alignment, reason=f"{alignment.reason}; wheels: {wheels.reason}")
        if not alignment.observable:
            self.status = f"scale not yet observable: {alignment.reason}"
            return
        self._start(alignment, "visual-inertial")

    def _start(self, alignment: InertialAlignment, source: str) -> None:
        t, T_map_cam = self._keyframes[-1]
        state = alignment.nav_state(t, T_map_cam, self.T_body_cam, alignment.velocities_map[-1])
        self.filter = NavigationFilter(state, self.settings, self._start_covariance())
        self.alignment, self.initialised_at = alignment, t
        self.status = f"initialised at {t:.3f} s from {source}: scale {alignment.scale:.4g} m per map unit"
        start = next((i for i in range(len(self._imu) - 1, -1, -1) if self._imu[i].timestamp <= t), 0)
        for sample in self._imu[start:]:
            warning = self.filter.propagate(sample)
            if warning is not None:
                self.warnings.append(warning.message)
        start_wheel = next((i for i, w in enumerate(self._wheel) if w.timestamp > t), len(self._wheel))
        for record in self._wheel[start_wheel:]:
            self._observe_wheels(record)
        self._imu, self._keyframes, self._wheel = [], [], []

    def _start_covariance(self) -> np.ndarray:
        """The prior (settings) with what the alignment determined narrowed to the START_ sigmas."""
        variances = np.diag(initial_covariance(self.settings)).copy()
        for states, sigma in (
            (POSITION, START_POSITION_SIGMA_M),
            (VELOCITY, START_VELOCITY_SIGMA_M_S),
            (ATTITUDE, START_ATTITUDE_SIGMA_RAD),
            (LOG_SCALE, START_LOG_SCALE_SIGMA),
            (MAP_ATTITUDE, START_MAP_ATTITUDE_SIGMA_RAD),
            (MAP_POSITION, START_MAP_POSITION_SIGMA_M),
        ):
            variances[states] = sigma**2
        return np.diag(variances)
