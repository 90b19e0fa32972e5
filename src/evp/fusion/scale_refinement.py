"""The visual map's scale measured again after the filter has started: ORB-SLAM3's inertial-only
optimisations after its initialisation, here the maximum-likelihood refinement
(:func:`~evp.fusion.inertial_refinement.refine_inertial`) over the keyframes kept since the map
began (those the start's own refinement had, up to 30 s, every other one; then one each 0.5 s, at
most MAX_KEYFRAMES, the first always kept), seeded by the filter's own scale and gravity, its
answer fused as a :class:`RefinedScale`.

Why: a visual-inertial start takes the first window whose scale is determined well enough to
start a filter (10 %); on a slow walk the motion barely tells the scale from an accelerometer
bias, and the filter, with one IMU interval at a time, then takes ten seconds and more to leave a
wrong start (the rendered circle's seed 2 started 22 % off and was still 5 % off after 23 s).
The refinement over all the keyframes since the standing start weighs each interval's
preintegration at once and carries the bias as an unknown; its sigma comes from the same system.

When (:data:`REFINE_AFTER_S`): ORB-SLAM3 (Campos et al. 2021, section V-B) re-runs its
inertial-only optimisation 5 s and 15 s after its start, which comes after 2 s of keyframes; ours
starts after about one second, so two earlier runs (1 s and 2.5 s) come first (the rendered
circles' fused SE3 ATE 2.9 / 7.5 / 0.9 cm with 5 and 15 s alone, 2.9 / 3.6 / 0.9 cm with them).
No later ones: ORB-SLAM3's scale refinements up to 75 s adjust the map jointly; a single scale
fitted to a minute of a drone's keyframes claimed 0.1 % where SLAM's map scale had moved 4 % (the
rendered 300 s flight, 5.2 -> 5.4 m per unit between 30 and 80 s). The stage takes a refinement
only while the filter's scale rests on the IMU and vision (no GPS fix or wheel speed fused yet),
and only where its sigma is below the filter's.

Where the map's scale is not one number over the keyframes (a downward camera's climb: SLAM's map
scale changes with the height), one scale fitted to all of them is none of them however small its
sigma (the 300 s flight's climb: 5.16 +- 0.5 % over all, 5.59 +- 0.6 % over the newer half, the
truth at cruise 5.49). The refinement over the newer half is compared with the whole's; beyond
CONSISTENCY_SIGMAS the newer half's is the answer and the older keyframes are left out from then on.

Pure: poses and IMU samples in, a measurement (or the reason there is none) out.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

import numpy as np

from evp.config import NavigationSettings
from evp.fusion.inertial_refinement import refine_inertial, white_position_noise
from evp.fusion.measurements import RefinedScale
from evp.fusion.nav_state import NavState
from evp.fusion.preintegration import drop_before
from evp.fusion.visual_inertial_init import InertialAlignment
from evp.types import ImuSample

# seconds after the filter's start at which the scale is refined again (ORB-SLAM3's schedule)
REFINE_AFTER_S = (1.0, 2.5, 5.0, 15.0)
# The newer half's scale replaces the whole's when they differ by more than this many sigmas of
# their difference: SLAM's map scale changed over the keyframes (the rendered drone's climb, a
# downward camera: 24 sigmas; the circles and EuRoC MH01 within 1.2)
CONSISTENCY_SIGMAS = 3.0
# keyframes kept 0.5 s apart from the map's first: 15 s after a start 30 s in
MAX_KEYFRAMES = 90
KEYFRAME_INTERVAL_S = 0.5
NOISE_POSES = 60  # the newest tracked poses whose second differences give the position noise


@dataclass(frozen=True)
class Refined:
    """One refinement's outcome: ``measurement`` to fuse, or None and ``reason``; with a
    measurement, ``reason`` says when it spans only the newer half (the map's scale changed)."""

    timestamp: float
    measurement: RefinedScale | None
    reason: str = ""


class ScaleRefinement:
    """Keeps the keyframes and IMU samples since the visual map's first keyframe; :meth:`due` says
    when the next refinement is scheduled, :meth:`refine` measures the scale."""

    def __init__(self, T_body_cam: np.ndarray, settings: NavigationSettings, started_at: float, keyframes, imu: list[ImuSample], recent):
        self.T_body_cam = T_body_cam
        self.settings = settings
        self.started_at = started_at
        self._keyframes = list(keyframes)
        self._imu = list(imu)
        self._recent: deque = deque(recent, maxlen=NOISE_POSES)
        self._next = 0

    @property
    def finished(self) -> bool:
        return self._next >= len(REFINE_AFTER_S)

    @property
    def span_start(self) -> float:
        """The time of the first keyframe a refinement spans (the map's first, until its scale
        was found to have changed since)."""
        return self._keyframes[0][0]

    def add_imu(self, sample: ImuSample) -> None:
        if not self.finished:
            self._imu.append(sample)

    def add_pose(self, timestamp: float, T_map_cam: np.ndarray) -> None:
        if self.finished:
            return
        self._recent.append((timestamp, T_map_cam))
        if not self._keyframes or timestamp - self._keyframes[-1][0] >= KEYFRAME_INTERVAL_S:
            self._keyframes.append((timestamp, T_map_cam))
            if len(self._keyframes) > MAX_KEYFRAMES:  # thinned after the first: the standing start is what separates scale and bias
                del self._keyframes[1]
            drop_before(self._imu, self._keyframes[0][0])

    def due(self, timestamp: float) -> bool:
        return not self.finished and timestamp - self.started_at >= REFINE_AFTER_S[self._next]

    def refine(self, state: NavState) -> Refined:
        """The scale over the kept keyframes an IMU sample reaches, seeded by the filter's ``state``;
        the next refinement is scheduled whatever the outcome."""
        self._next += 1
        while not self.finished and self._keyframes[-1][0] - self.started_at >= REFINE_AFTER_S[self._next]:
            self._next += 1  # a gap in the tracking skipped some
        keyframes = [k for k in self._keyframes if k[0] <= self._imu[-1].timestamp] if self._imu else []
        if len(keyframes) < self.settings.vi_init_min_keyframes:
            return Refined(self._keyframes[-1][0], None, "too few keyframes with IMU samples")
        gravity_map = state.R_world_map.T @ np.array([0.0, 0.0, -self.settings.gravity_m_s2])
        seed = InertialAlignment(True, scale=state.scale, gravity_map=gravity_map, gyro_bias=state.gyro_bias.copy())
        noise = white_position_noise([t for t, _ in self._recent], [T[:3, 3] for _, T in self._recent])
        alignment = refine_inertial(keyframes, self._imu, self.T_body_cam, seed, self.settings, position_sigma_map=noise)
        t = keyframes[-1][0]
        if not alignment.observable:
            return Refined(t, None, alignment.reason)
        newer, changed = self._newer_half(keyframes, alignment, noise)
        if changed:  # the older half's scale was another: the span starts at the newer half from now on
            del self._keyframes[: len(keyframes) // 2]
            alignment = newer
        return Refined(t, RefinedScale(t, alignment.scale, alignment.scale_sigma, self.T_body_cam), changed)

    def _newer_half(self, keyframes, alignment: InertialAlignment, noise) -> tuple[InertialAlignment | None, str]:
        """The refinement over the newer half of ``keyframes`` and why the map's scale is not one
        number over all of them, when it differs from ``alignment`` (over all) by more than
        CONSISTENCY_SIGMAS of the difference of two nested estimates (its variance is the half's
        minus the whole's); else (None, "")."""
        half = keyframes[len(keyframes) // 2 :]
        if len(half) < self.settings.vi_init_min_keyframes:
            return None, ""
        newer = refine_inertial(half, self._imu, self.T_body_cam, alignment, self.settings, position_sigma_map=noise)
        if not newer.observable:
            return None, ""
        spread = math.sqrt(max(newer.scale_sigma**2 - alignment.scale_sigma**2, alignment.scale_sigma**2))  # at least the whole's own
        if abs(math.log(newer.scale / alignment.scale)) <= CONSISTENCY_SIGMAS * spread:
            return None, ""
        return newer, (
            f"the map's scale changed over its keyframes ({alignment.scale:.4g} m per map unit +- {100 * alignment.scale_sigma:.1f} % over all): "
            f"over the newer half, from {half[0][0]:.3f} s on"
        )
