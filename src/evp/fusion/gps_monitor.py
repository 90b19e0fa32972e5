"""Online consistency check of GPS against the aligned visual track (spoofing and jamming).

Each fix gives an innovation: GPS east/north minus the visual position at the same time, after
the visual track's slowly estimated drift correction. Over a sliding window the mean innovation is
tested against a chi-square bound (2 dof) on its covariance: GPS noise (correlated, so averaging
does not shrink it) plus the visual drift accumulated since the last realignment. While GPS is
consistent the drift correction follows it (realignment on the fly, rate-limited so that a slow
spoofer cannot drag it along); an inconsistent window marks GPS untrusted and raises an alarm;
trust returns only after a sustained consistent period. No fix for a while means jamming.
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass, field

import numpy as np
from scipy.stats import chi2

from evp.config import MonitorSettings


class GpsTrust(enum.Enum):
    TRUSTED = "trusted"
    UNTRUSTED = "untrusted"  # spoofing suspected: position from vision only
    UNAVAILABLE = "unavailable"  # no fixes (jamming, outage)


@dataclass(frozen=True)
class MonitorEvent:
    timestamp: float
    kind: str  # spoofing_alarm, gps_lost, gps_back, trust_restored
    message: str


@dataclass
class GpsMonitor:
    """Feed it fixes with the aligned visual position at the same time: ``update(t, gps_en, visual_en, travelled_m)``."""

    settings: MonitorSettings = field(default_factory=MonitorSettings)
    trust: GpsTrust = GpsTrust.TRUSTED
    correction: np.ndarray = field(default_factory=lambda: np.zeros(2))  # added to the visual track
    events: list[MonitorEvent] = field(default_factory=list)
    _window: list[tuple[float, np.ndarray]] = field(default_factory=list)
    _last_fix_t: float | None = None
    _consistent_since: float | None = None
    _travelled_at_realign: float = 0.0
    _previous_trust: GpsTrust = GpsTrust.TRUSTED

    @property
    def threshold(self) -> float:
        return float(chi2.ppf(1.0 - self.settings.false_alarm_probability, 2))

    def _sigma(self, travelled_m: float) -> float:
        s = self.settings
        drift = s.visual_sigma_floor_m + s.visual_drift_m_per_m * max(0.0, travelled_m - self._travelled_at_realign)
        return math.hypot(s.gps_sigma_m, drift)

    def without_fixes(self) -> None:
        """The world was georeferenced without GPS (a saved map's georeference), or on fixes that
        have since stopped (GPS lost before the heading fit had its track): GPS is
        unavailable until a fix comes, and that fix is checked for ``recovery_s`` before it is
        trusted, as after a loss (a receiver that first locks mid-flight may be a spoofer's)."""
        self._previous_trust = GpsTrust.TRUSTED
        self.trust = GpsTrust.UNAVAILABLE

    def check_outage(self, t: float) -> None:
        """Call between fixes (e.g. every frame) so that jamming is noticed without a fix arriving."""
        if self._last_fix_t is not None and self.trust is not GpsTrust.UNAVAILABLE and t - self._last_fix_t > self.settings.outage_s:
            self._previous_trust = self.trust
            self.trust = GpsTrust.UNAVAILABLE
            self._window.clear()
            self.events.append(MonitorEvent(t, "gps_lost", f"no GPS fix for {t - self._last_fix_t:.1f} s (jamming or outage): position from vision"))

    def update(self, t: float, gps_en: np.ndarray, visual_en: np.ndarray, travelled_m: float) -> tuple[GpsTrust, float]:
        """Test one fix; returns the trust state and the test statistic (chi-square, 2 dof)."""
        s = self.settings
        self.check_outage(t)
        if self.trust is GpsTrust.UNAVAILABLE:
            self.trust = self._previous_trust
            self.events.append(MonitorEvent(t, "gps_back", "GPS fixes are back"))
            if self.trust is GpsTrust.TRUSTED:  # re-check consistency before following it again
                self.trust = GpsTrust.UNTRUSTED
                self._consistent_since = t
        self._last_fix_t = t
        innovation = np.asarray(gps_en, float) - (np.asarray(visual_en, float) + self.correction)
        self._window.append((t, innovation))
        while self._window and self._window[0][0] < t - s.window_s:
            self._window.pop(0)
        mean = np.mean([v for _, v in self._window], axis=0)
        sigma = self._sigma(travelled_m)
        statistic = float(mean @ mean / sigma**2)
        consistent = statistic <= self.threshold
        if self.trust is GpsTrust.TRUSTED:
            if consistent:
                self._realign(innovation, travelled_m)
            else:
                self.trust = GpsTrust.UNTRUSTED
                self._consistent_since = None
                self.events.append(
                    MonitorEvent(
                        t,
                        "spoofing_alarm",
                        f"GPS disagrees with vision by {math.hypot(*mean):.1f} m (chi2 {statistic:.0f} > {self.threshold:.0f}): GPS untrusted",
                    )
                )
        else:
            if not consistent:
                self._consistent_since = None
            elif self._consistent_since is None:
                self._consistent_since = t
            elif t - self._consistent_since >= s.recovery_s:
                self.trust = GpsTrust.TRUSTED
                self._travelled_at_realign = travelled_m
                self.events.append(MonitorEvent(t, "trust_restored", f"GPS consistent with vision for {s.recovery_s:.0f} s: trusted again"))
        return self.trust, statistic

    def _realign(self, innovation: np.ndarray, travelled_m: float) -> None:
        """Move the drift correction towards consistent GPS, no faster than the configured rate."""
        s = self.settings
        dt = self._window[-1][0] - self._window[-2][0] if len(self._window) > 1 else 0.1
        step = innovation * min(1.0, dt / s.realign_time_constant_s)
        limit = s.max_correction_rate_m_s * dt
        norm = float(np.linalg.norm(step))
        if norm > limit:
            step *= limit / norm
        self.correction = self.correction + step
        if norm < limit:
            self._travelled_at_realign = travelled_m
