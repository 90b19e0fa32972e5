"""Even degradation when the station's CPU is overloaded: fewer frames per session, said so.

The station's event loop does every session's link, recording and bookkeeping; when the machine
is short of CPU it falls behind, and then every link suffers together (answers late, WebSocket
pongs late, links cut: issue 34 measured 0.9 poses/s each for eight SLAM clients). The
governor watches how late the loop's one-second tick runs and, past ``station.overload_lag_s``,
caps every session at the same frame rate: 70 % of what the sessions sent on average, never
below ``overload_min_fps``; phones are asked for that rate (a config message), and frames
above it are answered ``dropped: overload`` before they cost anything. After
``overload_recover_s`` without lag the cap rises by a quarter each tick until it is lifted.
"""

from __future__ import annotations

from dataclasses import dataclass

from evp.config import StationSettings

SHARE_WHEN_BEHIND = 0.7  # of the mean rate the sessions sent: room for the loop to catch up
RISE_WHEN_CALM = 1.25  # per tick once calm: back to full rate within a few seconds


@dataclass
class LoadGovernor:
    settings: StationSettings
    cap_fps: float | None = None  # None: no cap
    _calm_since: float | None = None

    def tick(self, now: float, lag_s: float, session_rates_fps: list[float], full_fps: float) -> float | None | bool:
        """One tick: the loop ran ``lag_s`` late, the streaming sessions sent these frame rates,
        phones stream at ``full_fps`` uncapped. Returns the new cap (None: lifted) when it
        changed, else False."""
        s = self.settings
        if lag_s > s.overload_lag_s and session_rates_fps:
            self._calm_since = None
            mean = sum(session_rates_fps) / len(session_rates_fps)
            cap = round(max(s.overload_min_fps, SHARE_WHEN_BEHIND * min(mean, self.cap_fps or mean)), 1)
            if self.cap_fps is not None and cap >= self.cap_fps:
                return False
            self.cap_fps = cap
            return cap
        if self.cap_fps is None or lag_s > s.overload_lag_s / 2:
            self._calm_since = None
            return False
        if self._calm_since is None:
            self._calm_since = now
        if now - self._calm_since < s.overload_recover_s:
            return False
        raised = round(self.cap_fps * RISE_WHEN_CALM, 1)
        self.cap_fps = None if raised >= full_fps else raised
        return self.cap_fps
