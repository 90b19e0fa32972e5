"""A whole flight through the seed 002 system: odometry, alignment to GPS, barometric altitude,
the horizontal errors against GPS after the alignment phase, and the GPS consistency monitor
(spoofing/jamming). Their statistics and figures are in ``evp.eval.flight_report``."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from evp.atmosphere import altitude_from_pressure
from evp.config import AlignmentSettings, MonitorSettings
from evp.fusion.gps_alignment import AlignmentResult, align_flight, alignment_window, horizontal_errors_after, resample
from evp.fusion.gps_input import AlignmentError, GpsTrack, clean_gps
from evp.fusion.gps_monitor import GpsMonitor
from evp.types import BaroSample, GpsFix, Trajectory

NEAR_TARGET_M = 2.0  # seed 002's subset: |z - target| < 2 m


@dataclass
class FlightResult:
    gps: GpsTrack
    alignment: AlignmentResult
    errors_m: np.ndarray  # horizontal error at each GPS fix after the alignment phase
    error_heights_m: np.ndarray
    trust: list[tuple[float, str]]  # (GPS time, trust state) after the alignment phase
    monitor: GpsMonitor


def baro_heights(baro: list[BaroSample]) -> Trajectory | None:
    """Barometric height above the first sample (m), as a position-only trajectory (z)."""
    if not baro:
        return None
    times = np.array([b.timestamp for b in baro])
    altitude = np.array([b.altitude_m for b in baro])
    if not np.isfinite(altitude).all():  # pressure only: invert the standard atmosphere
        altitude = altitude_from_pressure(np.array([b.pressure_pa for b in baro]))
    up = altitude - altitude[0]
    zeros = np.zeros(len(times))
    return Trajectory(np.column_stack([zeros, zeros, up]), np.tile([0.0, 0.0, 0.0, 1.0], (len(times), 1)), times, "baro")


def monitor_flight(alignment: AlignmentResult, gps: GpsTrack, settings: MonitorSettings, max_gap_s: float) -> tuple[GpsMonitor, list[tuple[float, str]]]:
    """Replay the fixes after the alignment phase through the consistency monitor."""
    after = np.flatnonzero(gps.times > alignment.window[1])
    if len(gps) > 1:  # sparse GPS (one fix per survey photo): an outage is a multiple of its spacing
        spacing = float(np.median(np.diff(gps.times)))
        settings = settings.model_copy(update={"outage_s": max(settings.outage_s, 3.0 * spacing), "window_s": max(settings.window_s, 1.5 * spacing)})
    monitor = GpsMonitor(settings)
    visual, ok = resample(alignment.aligned, gps.times[after] - alignment.clock_offset_s, max_gap_s=max_gap_s)
    steps = np.linalg.norm(np.diff(visual[:, :2], axis=0), axis=1) if len(visual) > 1 else np.zeros(0)
    travelled = np.concatenate([[0.0], np.cumsum(np.where(np.isfinite(steps), steps, 0.0))])
    trust = []
    frame_times = alignment.aligned.timestamps + alignment.clock_offset_s  # on the GPS clock
    next_frame = int(np.searchsorted(frame_times, alignment.window[1]))
    for k, index in enumerate(after):
        while next_frame < len(frame_times) and frame_times[next_frame] < gps.times[index]:
            monitor.check_outage(float(frame_times[next_frame]))  # frames keep coming while GPS is silent
            next_frame += 1
        if not ok[k]:
            continue
        state, _ = monitor.update(float(gps.times[index]), gps.enu[index, :2], visual[k, :2], float(travelled[k]))
        trust.append((float(gps.times[index]), state.value))
    return monitor, trust


def choose_segment(segments: list[Trajectory], gps: GpsTrack, settings: AlignmentSettings, align_fraction: float | None) -> tuple[Trajectory, list[str]]:
    """The visual segment with most poses in the alignment phase; the others cannot share its
    transform (another frame and scale), which is said in the returned warnings."""
    start, end, _ = alignment_window(gps, settings, align_fraction)
    counts = [int(np.sum((s.timestamps >= start - 5.0) & (s.timestamps <= end + 5.0))) for s in segments]
    best = int(np.argmax(counts))
    warnings = [
        f"visual tracking restarted: poses {s.timestamps[0]:.1f}-{s.timestamps[-1]:.1f} s are in another frame and are not aligned"
        for k, s in enumerate(segments)
        if k != best
    ]
    return segments[best], warnings


def process_flight(
    gps_fixes: list[GpsFix],
    baro: list[BaroSample],
    odometry: Trajectory | list[Trajectory],
    settings: AlignmentSettings,
    monitor_settings: MonitorSettings,
    align_fraction: float | None = None,
) -> FlightResult:
    """``odometry`` is one visual track, or its segments between tracking losses; ``baro`` may be
    empty (3-D alignment then keeps the transformed altitude)."""
    gps = clean_gps(gps_fixes)
    segment_warnings: list[str] = []
    if isinstance(odometry, list):
        if not odometry:
            raise AlignmentError("the visual odometry tracked no frame: nothing to align")
        odometry, segment_warnings = choose_segment(odometry, gps, settings, align_fraction)
    if len(odometry) > 1:  # sparse imagery (survey photos seconds apart): interpolate across its spacing
        spacing = float(np.median(np.diff(odometry.timestamps)))
        settings = settings.model_copy(update={"max_gap_s": max(settings.max_gap_s, 3.0 * spacing)})
    alignment = align_flight(odometry, gps, baro_heights(baro), settings, align_fraction)
    alignment.warnings.extend(segment_warnings)
    errors, heights = horizontal_errors_after(alignment, gps, settings.max_gap_s)
    monitor, trust = monitor_flight(alignment, gps, monitor_settings, settings.max_gap_s)
    return FlightResult(gps, alignment, errors, heights, trust, monitor)
