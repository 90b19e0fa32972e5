"""One MAVLink output per vehicle: which endpoint and system id each session's poses go to.

A session whose mobile station's device name (``hello.device``) is in ``mavlink.vehicles`` gets
that endpoint; every other one shares the station's ``--mavlink`` endpoint with a system id of its
own (``mavlink.system_id``, the next free one for each further vehicle), so a router or the
autopilots can tell them apart. An endpoint that cannot be opened (a TCP autopilot that is down)
is an operator event; the session goes on and the output is tried again on a later pose.
"""

from __future__ import annotations

import time
from collections.abc import Callable

from evp.config import MavlinkSettings
from evp.station.mavlink_out import MavlinkOutput

RETRY_S = 5.0  # an endpoint that would not open is tried again after this long

# GPS events relayed to the pilot as STATUSTEXT, with MAVLink's severities (MAV_SEVERITY:
# 2 critical, 4 warning, 6 info): a spoofer is critical (the autopilot's own GPS is lying too).
ALARM_SEVERITY = {"spoofing_alarm": 2, "gps_lost": 4, "gps_back": 6, "trust_restored": 6}


class MavlinkRoutes:
    def __init__(self, default_url: str | None, settings: MavlinkSettings, on_problem: Callable[[str, str], None]):
        self.default_url = default_url
        self.settings = settings
        self._on_problem = on_problem  # (session id, text), from any thread
        self.outputs: dict[str, MavlinkOutput] = {}
        self._failed_at: dict[str, float] = {}

    def route(self, device: str, taken: set[int]) -> tuple[str, int] | None:
        """(endpoint, system id) for a vehicle, or None when it has no endpoint."""
        if device in self.settings.vehicles:
            return self.settings.vehicles[device], self.settings.system_id
        if self.default_url is None:
            return None
        system_id = self.settings.system_id
        while system_id in taken:
            system_id += 1
        return self.default_url, system_id

    def output(self, session_id: str, device: str) -> MavlinkOutput | None:
        """The session's output, opened on its first pose."""
        output = self.outputs.get(session_id)
        if output is not None or time.monotonic() - self._failed_at.get(session_id, -RETRY_S) < RETRY_S:
            return output
        taken = {o.system_id for o in self.outputs.values() if o.url == self.default_url}
        route = self.route(device, taken)
        if route is None:
            return None
        url, system_id = route
        try:
            output = MavlinkOutput(url, self.settings, system_id, lambda text: self._on_problem(session_id, text))
        except OSError as exc:
            self._failed_at[session_id] = time.monotonic()
            self._on_problem(session_id, f"MAVLink endpoint {url} cannot be opened: {exc}; retrying every {RETRY_S:g} s")
            return None
        self.outputs[session_id] = output
        return output

    def alarm(self, session_id: str, device: str, code: str, text: str) -> None:
        """A GPS event for the pilot, on that vehicle's link."""
        output = self.outputs.get(session_id)
        if output is not None and code in ALARM_SEVERITY:
            output.statustext(ALARM_SEVERITY[code], f"EVP {device}: {text}")

    def release(self, session_id: str) -> None:
        output = self.outputs.pop(session_id, None)
        if output is not None:
            output.close()

    def close(self) -> None:
        for session_id in list(self.outputs):
            self.release(session_id)
