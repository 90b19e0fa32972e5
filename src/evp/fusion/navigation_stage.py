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
``T_visual_cam``). After a visual-inertial start (``refine_scale_after_start``), the scale is
refined again over the keyframes since the map began, 1, 2.5, 5 and 15 s after the start
(:mod:`evp.fusion.scale_refinement`), and replaces the filter's where it is known better
(``scale_refinement`` notices say each outcome). A change of the estimator's reset counter is a
jump of the visual poses, not motion: a relocalisation keeps the map's scale, a new map (SLAM
restarted) forgets it. A jump the estimator does not count (a loop correction) shows as visual poses the filter's gate refuses: once
it has refused all of them for ``visual_jump_reset_s``, the map's pose is re-anchored as after a
relocalisation (``visual_jump`` warning). Re-anchors that follow one another with hardly a pose
accepted between them are not the map jumping but the filter lost (its velocity or attitude
wrong, which a re-anchor keeps): unless GPS holds it, the filter is dropped and starts again from
the visual-inertial initialisation (``navigation_restarted`` warning).

GPS (``use_gps``): the first fix with a lock is the take-off point, the origin of the ENU frame
its fixes are converted to. The filter starts from vision and the IMU only (GPS alone does not
start it: before the visual-inertial initialisation the estimates pass unchanged), in the map's
levelled frame, heading unknown. The fixes from then on are paired with the filter's position
until the pairs spread ``gps_align_min_spread_m`` horizontally; the heading and origin fitted to
them (:func:`~evp.fusion.gps_heading.align_to_gps`) move the filter's world to ENU at the take-off
point (:meth:`NavigationFilter.move_world`, their uncertainty added to the covariance). From then
on every fix is checked by the seed-002 :class:`~evp.fusion.gps_monitor.GpsMonitor` against the
filter's predicted position, and fused as a :class:`~evp.fusion.measurements.GpsPosition` only
while the monitor says TRUSTED; the filter's chi-square gate is the second guard (a spoofer's slow
pull-off is gated before the monitor's window mean grows past its bound). Fixes without a lock
(NaN) are dropped with a warning; the monitor's events (spoofing alarm, GPS lost or back, trust
restored) are kept in ``gps_monitor.events`` and told as warnings. Each trusted fix (each fix of
the alignment phase) is also paired with the camera's position in the visual map; when GPS stops
being trusted (``hold_map_on_gps_loss``), the visual map's scale and pose fitted to those pairs
(:mod:`evp.fusion.gps_map_fit`) replace the filter's, the body moving with the map, and the scale,
attitude and horizontal placement are held (no update moves them; the barometer keeps the height)
until GPS is trusted again (``map_held`` / ``map_released``; a jump of the map frees its pose).

A saved map's georeference (``map_georeference``, :mod:`evp.fusion.map_georeference`: SLAM
started from a map saved by a georeferenced run): the world is ENU at the map's origin from the
start, and the first tracked pose (SLAM's relocalisation in the map) starts the filter from it at
once: position, attitude, the map's pose and scale from the georeference with its uncertainty,
velocity unknown; no visual-inertial initialisation, no GPS alignment (``georeferenced from the
saved map``). GPS, when there is any, is checked and fused from then on as after an alignment.
Should SLAM give up on the map (a reset that is not a relocalisation before the filter started:
a new map of its own), the georeference is dropped and the stage starts as without one.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace

import numpy as np

from evp.config import MonitorSettings, NavigationSettings
from evp.fusion.geodesy import EnuFrame
from evp.fusion.gps_heading import WorldAlignment, align_to_gps, horizontal_spread
from evp.fusion.gps_map_fit import GpsMapPairs, MapFit
from evp.fusion.gps_monitor import GpsMonitor, GpsTrust
from evp.fusion.inertial_refinement import refine_inertial, white_position_noise
from evp.fusion.innovation import Innovation, UpdateStatus
from evp.fusion.map_georeference import MapGeoreference
from evp.fusion.measurements import BaroAltitude, GpsPosition, RangeHeight, VisualPose, WheelSpeed, YawRate
from evp.fusion.nav_state import ATTITUDE, ERROR_DIM, LOG_SCALE, MAP_ATTITUDE, MAP_POSITION, POSITION, VELOCITY, NavState, skew3
from evp.fusion.navigation_filter import NavigationFilter, NavigationOutput, initial_covariance
from evp.fusion.preintegration import drop_before, imu_arrays, preintegrate, samples_between
from evp.fusion.scale_refinement import ScaleRefinement
from evp.fusion.visual_inertial_init import InertialAlignment, initialise_visual_inertial
from evp.fusion.wheel_init import initialise_from_wheels
from evp.types import BaroSample, Frame, GpsFix, ImuSample, PoseEstimate, RangeSample, TrackingState, WheelOdometry

# Keyframe spacings the visual-inertial alignment tries, as multiples of
# navigation.vi_init_keyframe_interval_s: a fast vehicle is solved at once at the configured
# spacing; a slow one (a walker) whose visual noise swamps 0.25 s of motion is solved over a 2x or
# 4x longer window (the rendered circle: at 0.25 s the scale was never determined, every 2nd
# keyframe of 20 gave it within 5-8 %). Longer windows also drift more in the visual map: 4x is
# where that stays below the noise.
VI_INIT_STRIDES = (1, 2, 4)

# 1-sigma uncertainties of the filter's start from a visual-inertial alignment. The world is the
# map's frame levelled, so the position, the map's origin and the heading are known at the start
# by definition (small sigmas keep the covariance well conditioned); VINS-Mono's alignment gives
# gravity to about a degree, velocities to a few cm/s; the scale starts with the uncertainty
# the alignment is allowed (navigation.vi_init_max_scale_sigma).
START_POSITION_SIGMA_M = 0.01
START_VELOCITY_SIGMA_M_S = 0.1
START_ATTITUDE_SIGMA_RAD = 0.02
START_MAP_ATTITUDE_SIGMA_RAD = 0.02
START_MAP_POSITION_SIGMA_M = 0.01
# With navigation.vi_init_refine, the keyframes kept from the first (30 s at 0.25 s): the
# refinement needs the standing start, which is what makes a walker's scale observable (the
# rendered circle's 10 s windows mid-lap left it at 11-13 % sigma).
REFINE_KEYFRAMES = 120
# the tracked poses whose second differences give the refinement its position noise: 2 s at 30 fps
NOISE_POSES = 60
# A visual-inertial start takes its velocity from the tracked poses of this last span (a straight
# line fitted to them, at least START_VELOCITY_POSES), times the alignment's scale: the
# alignment's own velocity at its newest keyframe is the least determined of its unknowns (seed
# 002's flight E, cruising straight at 8 m/s: 11.6 m/s 30 degrees off against the poses' 9.0 m/s
# at that scale; the filter then refused the visual poses and called the GPS spoofed), and the
# poses' velocity is the one the next visual updates measure.
START_VELOCITY_SPAN_S = 0.5
START_VELOCITY_POSES = 3
# Re-anchors of the visual map in a row, each followed by fewer than RESTART_ACCEPTED_POSES
# accepted poses, that mean the filter is lost rather than the map moved: a loop's correction is
# one re-anchor and then poses accepted; a lost filter's velocity keeps the next ones refused (the
# rendered 150 s square flight re-anchored every 1.07 s for two minutes, its altitude falling to
# -94 km through a barometer its gate refused too).
RESTART_AFTER_JUMPS = 3
RESTART_ACCEPTED_POSES = 5
# The fused kinds under which the filter's scale rests on the IMU and vision (heights measure it
# only through a climb, and the refinement's sigma is then compared with what they gave the
# filter): a refined scale may replace the filter's only while nothing else was fused.
SCALE_FROM_IMU_AND_VISION = {"imu", "visual", "baro", "range", "yaw_rate"}
# IMU samples kept while waiting to relocalise in a saved map: its start needs the one at or before
# the relocalised frame, which a frame's telemetry (up to its stamp) always brings in (1 s at 200 Hz).
SAVED_MAP_IMU_KEPT = 200


def position_quality(covariance: np.ndarray, zero_sigma_m: float) -> int:
    """0-100 (MAVLink's ``quality``) from a pose covariance: 100 for a known position, falling
    linearly with the horizontal 1-sigma to 0 at ``zero_sigma_m``."""
    sigma = math.sqrt(max(0.0, 0.5 * float(covariance[0, 0] + covariance[1, 1])))
    return int(round(100.0 * max(0.0, 1.0 - sigma / zero_sigma_m)))


@dataclass(frozen=True)
class NavigationRecord:
    """What the filter said at one frame: its output and the visual update's innovation (None
    when the frame was not tracked)."""

    output: NavigationOutput
    visual: Innovation | None


@dataclass(frozen=True)
class Notice:
    """Something the operator should hear of, as it happens: ``code`` names it (the filter's
    ``imu_not_finite`` / ``imu_out_of_order`` / ``imu_gap``, ``gps_no_lock``, ``visual_jump``, the GPS monitor's
    ``spoofing_alarm`` / ``gps_lost`` / ``gps_back`` / ``trust_restored``, and the ``info``
    milestones ``navigation_started`` / ``georeferenced`` / ``map_held`` / ``map_not_held`` /
    ``map_released``)."""

    timestamp: float
    level: str  # info, warning
    code: str
    text: str


@dataclass(frozen=True)
class AlignmentProgress:
    """Where the GPS heading fit stands (seed 002's alignment phase, shown live): the pairs of
    filter position and fix collected, their horizontal spread against the spread it needs, and,
    once fitted, the model and the fit's RMS horizontal residual."""

    pairs: int
    spread_m: float
    needed_m: float
    model: str | None = None
    residual_m: float | None = None


# The fit :func:`align_to_gps` makes: a heading about the vertical and a translation, the scale
# and gravity being the filter's (seed 002 chooses among models offline; live the filter already
# knows the scale, so only these four degrees of freedom are left).
ALIGNMENT_MODEL = "heading + translation (filter scale)"


@dataclass(frozen=True)
class GpsRecord:
    """One fix with a lock: in ENU at the take-off point, the monitor's verdict (None before the
    heading is known) and the filter's answer (None when it was not offered)."""

    timestamp: float
    enu: np.ndarray
    trust: GpsTrust | None
    update: Innovation | None


class NavigationStage:
    """A pipeline stage (``observe`` telemetry, ``process`` estimates); see the module docstring.
    ``reset_counter`` reads the estimator's discontinuity counter (``Estimator.reset_counter``)."""

    def __init__(
        self,
        T_body_cam: np.ndarray,
        settings: NavigationSettings | None = None,
        reset_counter: Callable[[], int] = lambda: 0,
        monitor_settings: MonitorSettings | None = None,
        map_georeference: MapGeoreference | None = None,
    ):
        self.settings = settings or NavigationSettings()
        self.T_body_cam = np.asarray(T_body_cam, float)
        self._reset_counter = reset_counter
        self._last_reset_count = reset_counter()
        self.status = "scale not yet observable: no tracked pose yet"
        self.notices: list[Notice] = []
        self.records: list[NavigationRecord] = []
        self.sensors_used: set[str] = set()
        self._last_imu_stamp = -math.inf
        self.enu_frame: EnuFrame | None = None  # the take-off point: the first GPS fix with a lock
        self.gps_records: list[GpsRecord] = []
        self._gps_locked = True  # False from a fix without lock until one with it (one warning per loss)
        self.last_tracking_state = TrackingState.NOT_INITIALIZED
        self.world_changes = 0  # jumps of the output frame: the filter's start (map units to metres) and the turn to ENU
        self._map_pairs = GpsMapPairs(self.T_body_cam)  # trusted fixes (all before the monitor runs) with the camera's visual-map position, since the map last jumped
        self._before_start(GpsMonitor(monitor_settings or MonitorSettings()))
        self.map_georeference = map_georeference  # the saved map's, until the filter starts from it (or SLAM leaves the map)
        if map_georeference is not None:
            self.enu_frame = EnuFrame(*map_georeference.origin)
            self.status = "waiting to relocalise in the saved map (georeferenced)"

    def _before_start(self, gps_monitor: GpsMonitor) -> None:
        """The state of a stage whose filter has not started: at construction, and again when a
        lost filter is dropped (:meth:`_restart`)."""
        self.filter: NavigationFilter | None = None
        self.alignment: InertialAlignment | None = None  # the initialisation that started the filter
        self.initialised_at: float | None = None
        self._imu: list[ImuSample] = []  # before the filter starts: the samples the initialisation needs
        self._wheel: list[WheelOdometry] = []  # before the filter starts: the wheel records, for the wheel start
        self._keyframes: list[tuple[float, np.ndarray]] = []
        self._recent: deque[tuple[float, np.ndarray]] = deque(maxlen=NOISE_POSES)  # before the start: the newest tracked T_map_cam
        self._baro: list[tuple[float, float]] = []  # before the filter starts: heights to check the initialisation's scale
        self._map_start: tuple[float, np.ndarray] | None = None  # before the filter starts: the map's first keyframe (time, T_map_cam)
        self._map_start_height = math.nan  # the barometer's height there, once measured (NaN: not yet, or no barometer)
        self._ground_height_m: float | None = None  # the range finder's ground, in world z, from its first reading
        self.world_alignment: WorldAlignment | None = None  # how the filter's world became ENU
        self.gps_monitor = gps_monitor
        self._gps_pairs: list[tuple[np.ndarray, np.ndarray]] = []  # (filter position, GPS ENU) before the heading is known
        self._last_paired_fix: GpsFix | None = None  # the newest of them: GPS lost while aligning is told by its age
        self._told_short_track = False  # GPS lost while aligning on too short a track: warned once per loss
        self._travelled_m = 0.0
        self._last_fix_position: np.ndarray | None = None
        self.alignment_progress: AlignmentProgress | None = None  # None until a fix is paired with the running filter
        self._gated_since: float | None = None  # the first of the visual poses the gate has refused in a row
        self._accepted_since_jump = 0  # visual poses accepted since the last re-anchor
        self._jumps_in_a_row = 0  # re-anchors each followed by fewer than RESTART_ACCEPTED_POSES accepted poses
        self._ahead: tuple[NavState, NavState, ImuSample] | None = None  # (filter state, it carried ahead, last sample): predict's cache
        self.map_fit: MapFit | None = None  # the fit the filter holds while GPS is not trusted
        self.scale_refinement: ScaleRefinement | None = None  # after a visual-inertial start: the scale measured again
        self._fused_since_start: set[str] = set()  # the measurement kinds this filter has fused

    @property
    def warnings(self) -> list[str]:
        """The texts of the warning notices (NaN or out-of-order IMU, gaps, GPS without lock, the
        GPS monitor's events), in order."""
        return [n.text for n in self.notices if n.level == "warning"]

    def _warn(self, timestamp: float, code: str, text: str) -> None:
        self.notices.append(Notice(timestamp, "warning", code, text))

    # --- telemetry -----------------------------------------------------------------------------

    def observe(self, record) -> None:
        """One telemetry record; kinds the stage does not fuse are ignored."""
        if isinstance(record, ImuSample):
            self._observe_imu(record)
        elif isinstance(record, GpsFix):
            if self.settings.use_gps:  # before the filter starts too: the first fix is the take-off point
                self._observe_gps(record)
        elif isinstance(record, WheelOdometry) and self.settings.use_wheels:
            self._observe_wheels(record)
        elif self.filter is None:
            if isinstance(record, BaroSample) and self.settings.use_baro and math.isfinite(record.altitude_m):
                self._baro.append((record.timestamp, record.altitude_m))
            return
        elif isinstance(record, BaroSample) and self.settings.use_baro:
            self._update(BaroAltitude(record.timestamp, record.altitude_m))
        elif isinstance(record, RangeSample) and self.settings.use_range:
            self._observe_range(record)

    def _observe_imu(self, sample: ImuSample) -> None:
        values = (sample.timestamp, *sample.angular_velocity_rad_s, *sample.linear_acceleration_m_s2)
        if not all(math.isfinite(v) for v in values):
            self._warn(sample.timestamp, "imu_not_finite", f"IMU sample at {sample.timestamp} holds NaN or infinite values: dropped")
            return
        if sample.timestamp <= self._last_imu_stamp:
            text = f"IMU sample at {sample.timestamp:.6f} s is not after the previous one ({self._last_imu_stamp:.6f} s): dropped"
            self._warn(sample.timestamp, "imu_out_of_order", text)
            return
        gap = sample.timestamp - self._last_imu_stamp
        self._last_imu_stamp = sample.timestamp
        self.sensors_used.add("imu")
        if self.filter is None:  # the filter reports its own gaps once it runs
            if self.settings.max_imu_gap_s < gap < math.inf:
                self._warn(
                    sample.timestamp, "imu_gap", f"{gap:.3f} s without IMU samples before {sample.timestamp:.6f} s (initialisation integrates across it)"
                )
            self._imu.append(sample)
            if self.map_georeference is not None:  # the start from the map uses only the sample before it
                del self._imu[:-SAVED_MAP_IMU_KEPT]
            return
        self._propagate(sample)
        if self.scale_refinement is not None:
            self.scale_refinement.add_imu(sample)

    def _propagate(self, sample: ImuSample) -> None:
        warning = self.filter.propagate(sample)
        if warning is not None:
            self._warn(warning.timestamp, warning.kind, warning.message)

    def _observe_range(self, sample: RangeSample) -> None:
        if self._ground_height_m is None:
            if not (math.isfinite(sample.distance_m) and sample.distance_m > 0):
                return
            # the ground under the first reading, straight down the body's -z (RangeHeight's default beam)
            state = self.filter.state
            self._ground_height_m = float(state.position[2] - sample.distance_m * state.R_world_body[2, 2])
        self._update(RangeHeight(sample.timestamp, sample.distance_m, self._ground_height_m))

    def _observe_gps(self, fix: GpsFix) -> None:
        geodetic = (fix.latitude_deg, fix.longitude_deg, fix.altitude_m)
        if not all(math.isfinite(v) for v in (fix.timestamp, *geodetic)):
            if self._gps_locked:
                text = f"GPS fix at {fix.timestamp:.3f} s has no lock (NaN or infinite position): GPS not fused until a fix has one"
                self._warn(fix.timestamp, "gps_no_lock", text)
            self._gps_locked = False
            return
        self._gps_locked = True
        if self.enu_frame is None:
            self.enu_frame = EnuFrame.at(fix)
        enu = self.enu_frame.to_enu(*geodetic)[0]
        if self.world_alignment is None:  # the alignment phase takes GPS as good (seed 002's)
            self._map_pairs.add_fix(fix.timestamp, enu)
        if self.filter is None:
            return
        position = self.filter.state.position
        if self._last_fix_position is not None:
            self._travelled_m += float(np.linalg.norm(position[:2] - self._last_fix_position[:2]))
        self._last_fix_position = position.copy()
        if self.world_alignment is None:
            self._gps_pairs.append((position.copy(), enu))
            self._last_paired_fix, self._told_short_track = fix, False
            self.gps_records.append(GpsRecord(fix.timestamp, enu, None, None))
            self._try_alignment(fix)
            return
        events = len(self.gps_monitor.events)
        trust, _ = self.gps_monitor.update(fix.timestamp, enu[:2], position[:2], self._travelled_m)
        self._follow_monitor_events(events)
        update = None
        if trust is GpsTrust.TRUSTED:
            update = self._update(GpsPosition(fix.timestamp, tuple(enu), fix.horizontal_accuracy_m, fix.vertical_accuracy_m))
            if update.accepted:  # a spoofer's pull-off is gated within a second, long before the alarm
                self._map_pairs.add_fix(fix.timestamp, enu)
        self.gps_records.append(GpsRecord(fix.timestamp, enu, trust, update))

    def _try_alignment(self, fix: GpsFix) -> None:
        """Turn the filter's world to ENU once the paired fixes spread enough to give the heading."""
        local = np.array([p for p, _ in self._gps_pairs])
        spread = horizontal_spread(local)
        self.alignment_progress = AlignmentProgress(len(local), spread, self.settings.gps_align_min_spread_m)
        if spread >= self.settings.gps_align_min_spread_m:
            self._georeference(fix, local, spread)

    def _align_on_loss(self, timestamp: float) -> None:
        """GPS lost before the paired fixes spread enough: fit the heading on what they have when
        its uncertainty is within ``gps_align_on_loss_max_heading_sigma_deg`` (a warning says so);
        else warn once and wait (the pairs are kept should GPS come back)."""
        fix = self._last_paired_fix
        local = np.array([p for p, _ in self._gps_pairs])
        spread = horizontal_spread(local)
        heading_sigma_deg = math.degrees(self._fix_sigma(fix) / max(spread, 1e-9))
        lost = f"GPS lost at {timestamp:.3f} s (no fix since {fix.timestamp:.3f} s) with the paired fixes spread {spread:.1f} m, short of {self.settings.gps_align_min_spread_m:.0f} m"
        if heading_sigma_deg <= self.settings.gps_align_on_loss_max_heading_sigma_deg:
            self._warn(timestamp, "georeferenced_short_track", f"{lost}: heading fitted on them, 1-sigma {heading_sigma_deg:.0f} deg")
            self._georeference(fix, local, spread)
            self.gps_monitor.without_fixes()
            if self.settings.hold_map_on_gps_loss:
                self._hold_map(timestamp, timestamp)
        else:
            self._told_short_track = True
            self._warn(timestamp, "not_georeferenced", f"{lost}: a heading fitted on them (1-sigma {heading_sigma_deg:.0f} deg) is not worth having; not georeferenced")

    def _fix_sigma(self, fix: GpsFix) -> float:
        accuracy = fix.horizontal_accuracy_m
        return accuracy if math.isfinite(accuracy) and accuracy > 0 else self.settings.gps_default_sigma_m

    def _georeference(self, fix: GpsFix, local: np.ndarray, spread: float) -> None:
        """Fit the heading and origin to the paired fixes (``fix`` the newest; ``local`` the
        filter's positions, ``spread`` theirs) and move the filter's world to ENU with their
        uncertainty."""
        enu = np.array([e for _, e in self._gps_pairs])
        alignment = align_to_gps(local, enu, self._fix_sigma(fix))
        residuals = (local @ alignment.R.T + alignment.t) - enu
        residual = float(np.sqrt(np.mean(np.sum(residuals[:, :2] ** 2, axis=1))))
        self.alignment_progress = AlignmentProgress(len(local), spread, self.settings.gps_align_min_spread_m, ALIGNMENT_MODEL, residual)
        self.world_changes += 1
        # the receiver's correlated error moved the fit as much as the fixes: the filter's GPS
        # error state takes it; what the fit's residual shows of the track's own distortion
        # (its scale still settling) is the translation's doubt beside it, per axis
        fix_error = GpsPosition(fix.timestamp, tuple(enu[-1]), fix.horizontal_accuracy_m, fix.vertical_accuracy_m).variances(self.settings)
        distortion = np.sqrt(np.mean(residuals**2, axis=0))
        self.filter.move_world(
            alignment.R, alignment.t, alignment.pivot, distortion, alignment.yaw_sigma_rad, (1.0 - self.settings.gps_white_share) * fix_error
        )
        if self._ground_height_m is not None:
            self._ground_height_m += float(alignment.t[2])
        self._last_fix_position = alignment.R @ self._last_fix_position + alignment.t
        self.world_alignment, self._gps_pairs, self._last_paired_fix = alignment, [], None
        self.status += f"; georeferenced at {fix.timestamp:.3f} s (heading from {alignment.spread_m:.0f} m of GPS track)"
        text = f"georeferenced: {ALIGNMENT_MODEL} fitted to {len(local)} fixes over {spread:.0f} m, RMS residual {residual:.2f} m"
        self.notices.append(Notice(fix.timestamp, "info", "georeferenced", text))

    def _follow_monitor_events(self, first: int) -> None:
        """Tell the monitor's new events, and hold the map fitted to GPS when trust goes, release it when trust returns."""
        for event in self.gps_monitor.events[first:]:
            self._warn(event.timestamp, event.kind, f"GPS at {event.timestamp:.3f} s: {event.message}")
            if event.kind in ("spoofing_alarm", "gps_lost") and self.settings.hold_map_on_gps_loss and not self.filter.map_held:
                # a spoofer pulls the fixes for the monitor's window before the alarm: they are not fitted
                before = event.timestamp - (self.gps_monitor.settings.window_s if event.kind == "spoofing_alarm" else 0.0)
                self._hold_map(event.timestamp, before)
            elif event.kind == "trust_restored" and self.filter.map_held:
                self.filter.release_map()
                self.map_fit = None
                self.notices.append(Notice(event.timestamp, "info", "map_released", "GPS trusted again: the visual map's scale and attitude follow the fused sensors again"))

    def _hold_map(self, timestamp: float, before: float) -> None:
        """Fit the visual map to the trusted phase's fixes up to ``before`` and hold it (see
        :mod:`evp.fusion.gps_map_fit`); a notice says what was fitted, or why nothing was."""
        fit = self._map_pairs.fit(before, self.settings.gps_align_min_spread_m, self.settings.gps_correlation_time_s)
        if isinstance(fit, str):
            self.notices.append(Notice(timestamp, "info", "map_not_held", f"GPS not trusted: the visual map is not fitted to it ({fit}); the filter's own scale and map pose go on"))
            return
        own = self.filter.output()  # the filter's own scale, told beside the fit's
        self.filter.hold_map(math.log(fit.scale), fit.R_world_map, fit.t_world_map, fit.covariance)
        self.map_fit = fit
        self.world_changes += 1  # the body moved with the map: a jump of the answers
        scale_sigma = 100 * math.sqrt(fit.covariance[0, 0])
        text = (
            f"GPS not trusted: the visual map fitted to {fit.pairs} fixes over {fit.span_s:.0f} s ({fit.dropped} dropped), RMS residual "
            f"{fit.residual_m:.2f} m, scale {fit.scale:.4g} m per map unit +-{scale_sigma:.2f} % (the filter had {own.scale:.4g} "
            f"+-{100 * own.scale_sigma:.2f} %): held until GPS is trusted again"
        )
        self.notices.append(Notice(timestamp, "info", "map_held", text))

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
            self._fused_since_start.add(measurement.kind)
        return innovation

    # --- estimates -----------------------------------------------------------------------------

    def process(self, frame: Frame, estimate: PoseEstimate) -> PoseEstimate:
        """The estimate made metric once the filter runs; unchanged (``metric`` False) before."""
        self._follow_resets(estimate)
        tracked = estimate.tracking_state.tracked
        if tracked:
            self._map_pairs.add_pose(estimate.timestamp, estimate.T_world_cam)
        if self.filter is None:
            if tracked and self.map_georeference is not None:
                self._start_from_saved_map(estimate)
            elif tracked:
                self._collect(estimate)
            if self.filter is None:
                return estimate
        if self.world_alignment is not None:
            events = len(self.gps_monitor.events)
            self.gps_monitor.check_outage(estimate.timestamp)
            self._follow_monitor_events(events)
        elif (
            self._last_paired_fix is not None
            and not self._told_short_track  # told once per loss: the pairs do not change until GPS is back
            and estimate.timestamp - self._last_paired_fix.timestamp > self.gps_monitor.settings.outage_s
        ):
            self._align_on_loss(estimate.timestamp)
        visual = self._visual_update(estimate) if tracked else None
        if self.filter is None:  # restarted: it had lost the visual map
            return estimate
        if visual is not None and visual.accepted and self.scale_refinement is not None:  # a pose the gate refused may be a jumped map's
            self._refine_scale(estimate)
        output = self.filter.output(self.T_body_cam)
        self.records.append(NavigationRecord(output, visual))
        self.last_tracking_state = estimate.tracking_state
        return replace(estimate, T_world_cam=output.T_world_cam, T_visual_cam=estimate.T_world_cam, **self._fused_fields(output))

    def _visual_update(self, estimate: PoseEstimate) -> Innovation:
        """The tracked pose fused; once the gate has refused every pose for
        ``visual_jump_reset_s``, the visual map jumped without the estimator saying so (a loop
        correction): the map's pose is re-anchored at this one, its scale kept."""
        depth = math.nan if estimate.scene_depth is None else estimate.scene_depth
        pose = VisualPose(estimate.timestamp, estimate.T_world_cam, self.T_body_cam, depth)
        innovation = self._update(pose)
        if innovation.status is not UpdateStatus.GATED:
            self._gated_since = None
            self._accepted_since_jump += innovation.accepted
            return innovation
        if self._gated_since is None:
            self._gated_since = estimate.timestamp
        if estimate.timestamp - self._gated_since < self.settings.visual_jump_reset_s:
            return innovation
        self._gated_since = None
        self._jumps_in_a_row = self._jumps_in_a_row + 1 if self._accepted_since_jump < RESTART_ACCEPTED_POSES else 1
        self._accepted_since_jump = 0
        if self._jumps_in_a_row >= RESTART_AFTER_JUMPS and not self.gps_trusted:
            self._restart(estimate.timestamp)
            return innovation
        self.filter.reset_visual_map(estimate.timestamp, keep_scale=True)
        self.scale_refinement = None  # its keyframes are placed as before the jump
        self._map_pairs.clear()
        text = f"visual poses refused since {estimate.timestamp - self.settings.visual_jump_reset_s:.3f} s: the visual map jumped; its pose re-anchored at {estimate.timestamp:.3f} s"
        self._warn(estimate.timestamp, "visual_jump", text)
        return self._update(pose)

    def _restart(self, timestamp: float) -> None:
        """Drop a filter that lost the visual map (see the module docstring) and wait for the
        visual-inertial initialisation again, as at the start; the take-off point stays, the
        world (and any georeference) is made anew, GPS is judged afresh by a new monitor."""
        text = (
            f"visual poses refused again and again until {timestamp:.3f} s ({self._jumps_in_a_row} re-anchors, "
            f"fewer than {RESTART_ACCEPTED_POSES} poses accepted after each): the filter lost the visual map; it starts again"
        )
        self._warn(timestamp, "navigation_restarted", text)
        self._before_start(GpsMonitor(self.gps_monitor.settings))
        self.status = f"scale not yet observable: the filter restarted at {timestamp:.3f} s"
        self.world_changes += 1

    def _fused_fields(self, output: NavigationOutput) -> dict:
        """What a fused estimate takes from the filter besides its pose."""
        return {
            "covariance": output.covariance,
            "metric": True,
            "scale_known": output.scale_known,
            "georeferenced": output.georeferenced,
            "gps_trusted": self.gps_trusted,
            "velocity": output.velocity,
            "velocity_covariance": self.filter.covariance[VELOCITY, VELOCITY].copy(),
        }

    def predict(self, timestamp: float, pending: Sequence = ()) -> PoseEstimate | None:
        """The filter's answer for a frame at ``timestamp`` that vision has not seen (yet): its
        newest state carried through the IMU samples among the ``pending`` telemetry (records the
        stage has not been given: live, the filter waits for vision, PX4's delayed horizon) and
        on to ``timestamp`` at its velocity for at most ``predict_max_s``; None before the filter
        starts. The covariance is the filter's own, at its newest state."""
        if self.filter is None:
            return None
        output = self.filter.output(self.T_body_cam)
        state = self._carried_ahead([r for r in pending if isinstance(r, ImuSample)])
        T_world_body = np.eye(4)
        T_world_body[:3, :3], T_world_body[:3, 3] = state.R_world_body, state.position
        T_world_cam = T_world_body @ self.T_body_cam
        T_world_cam[:3, 3] += state.velocity * min(max(0.0, timestamp - state.timestamp), self.settings.predict_max_s)
        quality = position_quality(output.covariance, self.settings.quality_zero_sigma_m)
        fields = {**self._fused_fields(output), "velocity": state.velocity.copy()}
        return PoseEstimate(timestamp, T_world_cam, self.last_tracking_state, quality=quality, **fields)

    def _carried_ahead(self, imu_ahead: list[ImuSample]) -> NavState:
        """The filter's newest state carried through ``imu_ahead``; each sample is integrated
        once while the filter's state stays the same (answers come at 30 Hz, the samples at
        200 Hz: redoing the whole held second for each answer would cost 30 times as much)."""
        newest = self.filter.state
        start = None
        if self._ahead is not None and self._ahead[0] is newest:
            _, state, last = self._ahead
            start = (state, last)
            imu_ahead = [s for s in imu_ahead if s.timestamp > last.timestamp]
        state, last = self.filter.predicted(imu_ahead, start)
        if last is not None:
            self._ahead = (newest, state, last)
        return state

    def geodetic(self, position: np.ndarray) -> tuple[float, float, float] | None:
        """Latitude, longitude (degrees) and altitude (m, WGS-84) of a world position once the
        world is ENU at the take-off point; None before."""
        if self.world_alignment is None or self.enu_frame is None:
            return None
        lat, lon, alt = self.enu_frame.to_geodetic(np.asarray(position, float))[0]
        return float(lat), float(lon), float(alt)

    @property
    def gps_state(self) -> str:
        """GPS as the filter uses it: ``off`` (no fix with a lock yet, ``use_gps`` false, or waiting to relocalise in a saved map),
        ``aligning`` (pairing fixes for the heading fit), then the monitor's ``trusted`` /
        ``untrusted`` (spoofing suspected) / ``unavailable`` (jamming, outage)."""
        if self.enu_frame is None or self.map_georeference is not None:  # the latter: waiting to relocalise in a saved map
            return "off"
        if self.world_alignment is None:
            return "aligning"
        return self.gps_monitor.trust.value

    @property
    def gps_trusted(self) -> bool:
        """GPS is being fused: the world is ENU and the monitor trusts the fixes."""
        return self.world_alignment is not None and self.gps_monitor.trust is GpsTrust.TRUSTED

    def _follow_resets(self, estimate: PoseEstimate) -> None:
        count = self._reset_counter()
        if count == self._last_reset_count:
            return
        self._last_reset_count = count
        self._map_pairs.clear()
        if self.filter is None:
            self._keyframes.clear()  # the poses so far belong to another map (or before a jump)
            self._recent.clear()
            self._map_start, self._map_start_height = None, math.nan
            if self.map_georeference is not None and estimate.tracking_state is not TrackingState.RELOCALIZED:
                self._leave_saved_map(estimate.timestamp)
            return
        keep_scale = estimate.tracking_state is TrackingState.RELOCALIZED
        self.filter.reset_visual_map(estimate.timestamp, keep_scale)
        self.scale_refinement = None  # its keyframes are placed as before the jump

    def _collect(self, estimate: PoseEstimate) -> None:
        """Keep the pose as a keyframe when it is far enough after the last, and try to initialise:
        over the newest window of keyframes, then over windows of every 2nd and 4th one
        (:data:`VI_INIT_STRIDES`), from the IMU, else from the wheels. With ``vi_init_refine`` the
        first window whose alignment leaves the scale undetermined seeds the inertial refinement
        over every 2nd keyframe since the first (once an attempt), which starts the filter once its
        scale's sigma is small enough; the refinement's position noise is measured on the newest
        tracked poses."""
        s = self.settings
        self._recent.append((estimate.timestamp, estimate.T_world_cam.copy()))
        if self._keyframes and estimate.timestamp - self._keyframes[-1][0] < s.vi_init_keyframe_interval_s:
            return
        self._keyframes.append((estimate.timestamp, estimate.T_world_cam))
        if self._map_start is None:
            self._map_start = self._keyframes[-1]
        del self._keyframes[: -(REFINE_KEYFRAMES if s.vi_init_refine else s.vi_init_window_keyframes * VI_INIT_STRIDES[-1])]
        oldest = self._keyframes[0][0]
        drop_before(self._imu, oldest)
        drop_before(self._wheel, oldest)
        reasons, refined = [], False
        for stride in VI_INIT_STRIDES:
            window = self._keyframes[::-stride][: s.vi_init_window_keyframes][::-1]
            if stride > 1 and len(window) < s.vi_init_min_keyframes:
                break
            if s.vi_init_refine:  # the window's alignment, however uncertain, seeds the refinement over every keyframe
                alignment = initialise_visual_inertial(window, self._imu, self.T_body_cam, s.model_copy(update={"vi_init_max_scale_sigma": 1.0}))
            else:
                alignment = initialise_visual_inertial(window, self._imu, self.T_body_cam, s)
            if alignment.observable and s.vi_init_refine and alignment.scale_sigma > s.vi_init_max_scale_sigma:
                if refined:  # the refinement is over the same keyframes whichever window seeds it: once an attempt
                    alignment = replace(alignment, observable=False, reason=f"scale not yet determined: +-{100 * alignment.scale_sigma:.0f} %")
                else:
                    refined = True
                    history = self._keyframes[::-2][::-1]  # every keyframe since the first, 0.5 s apart
                    noise = white_position_noise([t for t, _ in self._recent], [T[:3, 3] for _, T in self._recent])
                    alignment = refine_inertial(history, self._imu, self.T_body_cam, alignment, s, position_sigma_map=noise)
                    window = history
                    if alignment.observable and not alignment.scale_sigma <= s.vi_refine_max_scale_sigma:
                        alignment = replace(alignment, observable=False, reason=f"refined scale not yet determined: +-{100 * alignment.scale_sigma:.1f} %")
            if alignment.observable:
                contradiction = self._baro_contradiction(alignment, window)
                if contradiction is None:
                    self._start(alignment, "visual-inertial")
                    return
                alignment = replace(alignment, observable=False, reason=contradiction)
            reasons.append(alignment.reason if stride == 1 else f"one keyframe in {stride}: {alignment.reason}")
        newest = self._keyframes[-s.vi_init_window_keyframes :]
        if self._wheel:
            wheels = initialise_from_wheels(newest, self._wheel, self._imu, self.T_body_cam, s)
            if wheels.observable:
                self._start(wheels, "wheel odometry")
                return
            reasons.append(f"wheels: {wheels.reason}")
        self.status = f"scale not yet observable: {'; '.join(reasons)}"

    def _baro_contradiction(self, alignment: InertialAlignment, window: list[tuple[float, np.ndarray]]) -> str | None:
        """Why the barometer's climb contradicts the alignment's scale, over the keyframe window or
        since the map's first keyframe; None when both agree within ``vi_init_baro_scale_tolerance``
        or climb too little to tell. A downward camera climbing straight up moves along its optical
        axis: the alignment can then find a consistent but wrong scale (5.8x off on the rendered
        drone flight's climb). A window at cruise altitude cannot see that, the climb since the map
        began can: seed 002's flight D started at 4.4x its map's scale on a level window, 109 m up."""
        interval = self.settings.vi_init_keyframe_interval_s

        def height(t: float) -> float:
            near = [h for s, h in self._baro if abs(s - t) <= interval]
            return float(np.mean(near)) if near else math.nan

        if self._map_start is not None and math.isnan(self._map_start_height):
            self._map_start_height = height(self._map_start[0])
        del self._baro[: next((i for i, (t, _) in enumerate(self._baro) if t >= window[0][0] - interval), len(self._baro))]
        (t0, T0), (t1, T1) = window[0], window[-1]
        spans = [("over the keyframe window", height(t1) - height(t0), T1[:3, 3] - T0[:3, 3])]
        if self._map_start is not None:
            spans.append(("since the map's first keyframe", height(t1) - self._map_start_height, T1[:3, 3] - self._map_start[1][:3, 3]))
        for span, climb_baro, step_map in spans:
            if not abs(climb_baro) >= self.settings.vi_init_baro_min_climb_m:  # NaN too: no barometer there
                continue
            climb_visual = alignment.scale * float((alignment.R_world_map @ step_map)[2])
            if abs(climb_visual / climb_baro - 1.0) > self.settings.vi_init_baro_scale_tolerance:
                return f"{span}, the barometer climbed {climb_baro:.1f} m where the visual-inertial scale ({alignment.scale:.3g} m per map unit) gives {climb_visual:.1f} m"
        return None

    def _refine_scale(self, estimate: PoseEstimate) -> None:
        """The scale refined again when it is due (:mod:`evp.fusion.scale_refinement`), taken
        where it is known better than the filter knows it; no more once a sensor that measures
        the scale on its own (GPS, wheels) has been fused: the refinement stands for what the
        IMU and vision alone say."""
        if self._fused_since_start - SCALE_FROM_IMU_AND_VISION:
            self.scale_refinement = None
            return
        refinement = self.scale_refinement
        refinement.add_pose(estimate.timestamp, estimate.T_world_cam)
        if not refinement.due(estimate.timestamp):
            return
        refined = refinement.refine(self.filter.state)
        if refinement.finished:
            self.scale_refinement = None  # its keyframes and IMU are not needed any more
        if refined.measurement is None:
            self.notices.append(Notice(refined.timestamp, "info", "scale_refinement", f"scale not refined at {refined.timestamp:.3f} s: {refined.reason}"))
            return
        m = refined.measurement
        known = math.sqrt(self.filter.covariance[LOG_SCALE, LOG_SCALE])  # relative: d(log s)
        if not m.sigma < known:
            text = f"scale refined at {m.timestamp:.3f} s to {m.scale:.4g} m per map unit +- {100 * m.sigma:.1f} %: not taken, the filter knows it better (+- {100 * known:.1f} %)"
            self.notices.append(Notice(m.timestamp, "info", "scale_refinement", text))
            return
        innovation = self.filter.update(m)
        span = f"; {refined.reason}" if refined.reason else ""
        text = f"scale refined at {m.timestamp:.3f} s over the map's keyframes: {m.scale:.4g} m per map unit +- {100 * m.sigma:.1f} %, {innovation.status.value}{span}"
        self.notices.append(Notice(m.timestamp, "info", "scale_refinement", text))

    def _start(self, alignment: InertialAlignment, source: str) -> None:
        t, T_map_cam = self._keyframes[-1]
        velocity_map = alignment.velocities_map[-1]
        if source == "visual-inertial":
            velocity_map = self._tracked_velocity(t, alignment, velocity_map)
        state = alignment.nav_state(t, T_map_cam, self.T_body_cam, velocity_map)
        camera_position = state.position + state.R_world_body @ self.T_body_cam[:3, 3]
        self.filter = NavigationFilter(state, self.settings, self._start_covariance(camera_position))
        self.alignment, self.initialised_at = alignment, t
        self.status = f"initialised at {t:.3f} s from {source}: scale {alignment.scale:.4g} m per map unit"
        self.world_changes += 1
        self.notices.append(Notice(t, "info", "navigation_started", f"navigation filter {self.status}"))
        if source == "visual-inertial" and self.settings.refine_scale_after_start:
            self.scale_refinement = ScaleRefinement(self.T_body_cam, self.settings, t, self._keyframes[::-2][::-1], self._imu, self._recent)
        start = next((i for i in range(len(self._imu) - 1, -1, -1) if self._imu[i].timestamp <= t), 0)
        for sample in self._imu[start:]:
            self._propagate(sample)
        start_wheel = next((i for i, w in enumerate(self._wheel) if w.timestamp > t), len(self._wheel))
        for record in self._wheel[start_wheel:]:
            self._observe_wheels(record)
        self._imu, self._keyframes, self._wheel, self._baro = [], [], [], []
        self._map_start = None

    def _tracked_velocity(self, t: float, alignment: InertialAlignment, fallback: np.ndarray) -> np.ndarray:
        """The body's velocity at ``t`` (metres per second, map axes): the slope of a straight line
        through the tracked positions of the last START_VELOCITY_SPAN_S, times the alignment's
        scale, is the velocity at their mean time (exactly so under constant acceleration); the
        IMU carries it on to ``t`` (preintegrated on the alignment's biases, gravity its). The
        camera's velocity stands for the body's: they differ by the rotation rate times the lever
        arm (1 cm/s for 10 cm at 0.1 rad/s). ``fallback`` when fewer than START_VELOCITY_POSES were
        tracked in the span."""
        recent = [(ti, T) for ti, T in self._recent if t - START_VELOCITY_SPAN_S <= ti <= t]
        if len(recent) < START_VELOCITY_POSES:
            return fallback
        times = np.array([ti for ti, _ in recent])
        middle = float(times.mean())
        slope = np.polyfit(times - middle, np.array([T[:3, 3] for _, T in recent]), 1)[0]
        imu_t, gyro, force = imu_arrays(self._imu)
        carried = preintegrate(*samples_between(imu_t, gyro, force - alignment.accel_bias, middle, t), alignment.gyro_bias)
        nearest = min(recent, key=lambda pose: abs(pose[0] - middle))[1]
        R_map_body = nearest[:3, :3] @ self.T_body_cam[:3, :3].T
        return alignment.scale * slope + R_map_body @ carried.dv + alignment.gravity_map * (t - middle)

    def _start_from_saved_map(self, estimate: PoseEstimate) -> None:
        """Start the filter at a pose in the saved map, from its georeference (see the module
        docstring): nothing to wait for, the map's scale, heading and origin are known."""
        geo, t = self.map_georeference, estimate.timestamp
        R_bc, t_bc = self.T_body_cam[:3, :3], self.T_body_cam[:3, 3]
        T_map_cam = estimate.T_world_cam
        R_world_body = geo.R @ T_map_cam[:3, :3] @ R_bc.T
        camera = geo.apply(T_map_cam[:3, 3][None])[0]
        state = NavState(
            t,
            camera - R_world_body @ t_bc,
            np.zeros(3),
            R_world_body,
            log_scale=math.log(geo.scale),
            R_world_map=geo.R.copy(),
            t_world_map=geo.t.copy(),
            map_anchored=True,
            georeferenced=True,
        )
        self.filter = NavigationFilter(state, self.settings, self._saved_map_covariance(state, camera - geo.t))
        self.initialised_at = t
        self.world_alignment = WorldAlignment(np.eye(3), np.zeros(3), camera, geo.rotation_sigma_rad, geo.translation_sigma_m, 0.0)
        self.gps_monitor.without_fixes()
        self.map_georeference = None
        self.world_changes += 1
        self.status = f"initialised at {t:.3f} s from the saved map's georeference: scale {geo.scale:.4g} m per map unit"
        text = (
            f"georeferenced from the saved map at {t:.3f} s: {geo.keyframes} keyframes fitted to ENU, "
            f"RMS residual {geo.residual_m:.2f} m, 1-sigma {geo.translation_sigma_m:.2f} m"
        )
        self.notices.append(Notice(t, "info", "navigation_started", f"navigation filter {self.status}"))
        self.notices.append(Notice(t, "info", "georeferenced", text))
        start = next((i for i in range(len(self._imu) - 1, -1, -1) if self._imu[i].timestamp <= t), 0)
        for sample in self._imu[start:]:
            self._propagate(sample)
        self._imu, self._keyframes, self._wheel, self._baro = [], [], [], []

    def _saved_map_covariance(self, state: NavState, camera_offset: np.ndarray) -> np.ndarray:
        """The prior with the map's pose and scale at the georeference's sigmas, the velocity
        unknown (``saved_map_velocity_sigma_m_s``), and the body's pose as uncertain as the map's
        pose makes it: the camera at ``x = s R x_map + t`` moves with the map's translation, its
        rotation (about the map's origin: ``camera_offset`` is the camera from there) and its
        scale, and turns with its rotation (fully correlated: one error moves both)."""
        geo = self.map_georeference
        map_states = np.r_[LOG_SCALE, MAP_ATTITUDE.start : MAP_ATTITUDE.stop, MAP_POSITION.start : MAP_POSITION.stop]
        P_map = np.diag([geo.log_scale_sigma**2, *[geo.rotation_sigma_rad**2] * 3, *[geo.translation_sigma_m**2] * 3])
        J = np.zeros((ERROR_DIM, 7))  # the error state from the map's errors (log scale, rotation, translation)
        J[LOG_SCALE, 0] = 1.0
        J[MAP_ATTITUDE, 1:4] = np.eye(3)
        J[MAP_POSITION, 4:7] = np.eye(3)
        J[POSITION, 0] = camera_offset
        J[POSITION, 1:4] = -skew3(camera_offset)
        J[POSITION, 4:7] = np.eye(3)
        J[ATTITUDE, 1:4] = state.R_world_body.T  # a world rotation, in the body's local error
        linked = np.r_[POSITION.start : POSITION.stop, ATTITUDE.start : ATTITUDE.stop, map_states]
        P = initial_covariance(self.settings)
        P[np.ix_(linked, linked)] = (J @ P_map @ J.T)[np.ix_(linked, linked)]
        P[POSITION, POSITION] += np.eye(3) * START_POSITION_SIGMA_M**2
        P[ATTITUDE, ATTITUDE] += np.eye(3) * START_ATTITUDE_SIGMA_RAD**2
        P[VELOCITY, VELOCITY] = np.eye(3) * self.settings.saved_map_velocity_sigma_m_s**2
        return P

    def _leave_saved_map(self, timestamp: float) -> None:
        """SLAM started a map of its own: the saved map's georeference no longer applies."""
        self.map_georeference, self.enu_frame = None, None
        self.status = "scale not yet observable: SLAM left the saved map for a new one"
        text = f"not relocalised in the saved map by {timestamp:.3f} s: SLAM started a new map; georeferencing by GPS as without a saved map"
        self._warn(timestamp, "saved_map_abandoned", text)

    def _start_covariance(self, camera_position: np.ndarray) -> np.ndarray:
        """The prior (settings) with what the alignment determined narrowed to the START_ sigmas.
        The world's origin is the map's, so the camera's position is the scale times its map
        position: its uncertainty along that direction is the scale's, fully correlated with it.
        Given as independent, a 1 cm position and origin would pin the scale to 1 cm over the
        distance from the map origin (1 % at 1 m) whatever the alignment's doubt: the rendered
        circle kept its start's -11 % scale to the end with a 1.2 % sigma. The scale's own sigma is
        the largest an alignment may have, not the alignment's least-squares one: that leaves out
        the accelerometer bias it neglects (with the truth's poses, the circle's swaying start gave
        a scale 18 % off with a least-squares sigma under 10 %)."""
        variances = np.diag(initial_covariance(self.settings)).copy()
        scale_sigma = self.settings.vi_init_max_scale_sigma
        for states, sigma in (
            (POSITION, START_POSITION_SIGMA_M),
            (VELOCITY, START_VELOCITY_SIGMA_M_S),
            (ATTITUDE, START_ATTITUDE_SIGMA_RAD),
            (LOG_SCALE, scale_sigma),
            (MAP_ATTITUDE, START_MAP_ATTITUDE_SIGMA_RAD),
            (MAP_POSITION, START_MAP_POSITION_SIGMA_M),
        ):
            variances[states] = sigma**2
        P = np.diag(variances)
        # d(position)/d(log scale) = the camera's offset from the map origin, metric, world axes
        P[POSITION, POSITION] += np.outer(camera_position, camera_position) * scale_sigma**2
        P[POSITION, LOG_SCALE] = P[LOG_SCALE, POSITION] = camera_position * scale_sigma**2
        return P
