"""A marker mission through the real station (``evp serve``): a simulated drone streams its
frames and sonar like a phone on a drone, the station's marker autopilot flies it with velocity
set-points over MAVLink, and the operator's mission page (headless Chromium) commands it: a
landing on an unmapped marker is refused, a landing on a mapped one lands the drone there."""

from __future__ import annotations

import asyncio
import shutil
import socket
import threading

import numpy as np
import pytest

from evp.mobile.client import StreamClient
from evp.sim.mission import marker_world_centres
from evp.station.marker_mission import parse_command
from tests.conftest import PROJECT
from tests.station.conftest import free_port, http_json, running_station

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
ARTIFACTS = PROJECT / "test-artifacts"
START = 49
CONFIG = """\
estimator: klt-vo
station:
  estimate_on_connect: false
autopilot:
  vehicles: [sim-drone]
"""


@pytest.mark.skipif(CHROMIUM is None, reason="Debian's chromium is not installed (scripts/test.sh installs it when it can)")
def test_a_land_command_from_the_operator_page_lands_the_drone_the_station_flies(tmp_path):
    sync_api = pytest.importorskip("playwright.sync_api")
    pytest.importorskip("pymavlink")
    from tests.station.sim_drone import SimulatedDrone

    config = tmp_path / "station.yaml"
    config.write_text(CONFIG)
    mavlink_port = free_port(socket.SOCK_DGRAM)
    drone = SimulatedDrone(f"udpin:127.0.0.1:{mavlink_port}", start_marker=START)
    centres = marker_world_centres()
    options = ("--config", str(config), "--mavlink", f"udpout:127.0.0.1:{mavlink_port}")
    with running_station(tmp_path / "data", *options) as station:
        client = StreamClient(station.url, device="sim-drone", insecure=True, log=lambda _text: None)
        streaming = threading.Thread(target=lambda: asyncio.run(client.run(drone.source(), realtime=True, encoding="png")), daemon=True)
        streaming.start()
        try:
            with sync_api.sync_playwright() as playwright:
                browser = playwright.chromium.launch(executable_path=CHROMIUM, args=["--no-sandbox"])
                context = browser.new_context(ignore_https_errors=True)
                operator = context.new_page()
                operator.goto(f"{station.http}/")
                operator.wait_for_selector("#mission-link:not([hidden])", timeout=60_000)  # the drone's session flies a mission
                mission_path = operator.get_attribute("#mission-link", "href")
                session_id = mission_path.split("session=")[1]
                page = context.new_page()
                page.goto(f"{station.http}{mission_path}")
                page.wait_for_function("['exploration', 'navigation'].includes(document.getElementById('state').textContent)", timeout=60_000)
                page.wait_for_function("parseInt(document.getElementById('mapped').textContent) >= 4", timeout=30_000)
                page.fill("#marker-id", "97")  # the far corner: not mapped yet
                page.click("#land-on")
                page.wait_for_function("document.getElementById('command-result').textContent.includes('refused')", timeout=10_000)
                _, view = http_json(station, "GET", f"/api/sessions/{session_id}/mission")
                target = max((m["id"] for m in view["markers"] if m["id"] != START), key=lambda i: np.linalg.norm(centres[i] - centres[START]))
                page.fill("#marker-id", str(target))
                page.click("#land-on")
                page.wait_for_function("document.getElementById('command-result').textContent.includes('accepted')", timeout=10_000)
                page.wait_for_function("document.getElementById('state').textContent === 'landed'", timeout=40_000)
                ARTIFACTS.mkdir(exist_ok=True)
                page.screenshot(path=str(ARTIFACTS / "marker_mission_page.png"))
                browser.close()
        finally:
            drone.stop.set()
            streaming.join(timeout=30)
            drone.close()
        _, events = http_json(station, "GET", f"/api/sessions/{session_id}/events")
    texts = [(e["code"], e["text"]) for e in events["events"]]
    assert any(code == "autopilot_command_rejected" and "97" in text for code, text in texts)
    assert any(code == "autopilot_command" and f"land {target}" in text for code, text in texts)
    assert drone.setpoints > 30  # the drone flew on the station's set-points
    landed_error = np.linalg.norm(drone.position[:2] - centres[target])
    assert landed_error <= 0.05, f"landed {landed_error * 1000:.0f} mm from marker {target}"


class Clock:
    def __init__(self):
        self.now = 0.0

    def __call__(self):
        return self.now


def test_the_station_side_of_a_mission_tells_the_operator_every_decision_on_bad_input():
    """The station's MarkerMission on rendered frames, without a flight controller: a command to
    an unmapped marker refused, a range finder that stops, a frame that does not decode, frames
    that stop (the watchdog holds): each a warning in the session's log, none a crash."""
    from evp.config import Settings
    from evp.sim.mission import MissionRun, MissionSpec
    from evp.station.marker_mission import MarkerMission
    from evp.station.protocol import ImageMessage, encode_image

    run = MissionRun(MissionSpec(seed=3, resolution=(240, 180), duration_s=10.0))
    run.vehicle.state.position[2] = 0.45  # over marker 49 at the flight level: the camera sees its neighbours
    told: list[tuple[str, str, str]] = []
    clock = Clock()
    mission = MarkerMission(run.renderer.camera, Settings(), lambda *event: told.append(event), lambda: None, clock)

    def frames(count: int, sonar: bool) -> None:
        for _ in range(count):
            image, reading = run.sense()
            if sonar:
                mission.on_range(reading)
            mission.on_frame(encode_image(image, round(run.t * 30), run.t, "png"))
            run.t = round(run.t + 1 / 30, 9)
            clock.now = run.t

    def warned(code: str) -> list[str]:
        return [text for level, kind, text in told if kind == code and level == "warning"]

    frames(30, sonar=True)
    assert mission.pilot.state.value in ("exploration", "navigation") and len(mission.pilot.marker_map) >= 4
    assert warned("autopilot_no_setpoint")  # no MAVLink route: nothing is sent, and the operator knows
    assert mission.command(parse_command({"kind": "land", "marker_id": 97})) == (False, "land 97: marker not in the map")
    assert warned("autopilot_command_rejected")
    frames(15, sonar=False)
    assert warned("autopilot_range_dropout")
    mission.on_frame(ImageMessage(999, run.t, "png", 240, 180, b"not a png"))
    assert warned("autopilot_bad_frame")
    clock.now += 1.0  # frames stop
    mission.tick()
    assert mission.last_command.holding and not mission.last_command.velocity_map.any()
    assert warned("autopilot_frames_stopped")
    with pytest.raises(ValueError, match="bad command"):
        parse_command({"kind": "goto", "marker_id": "forty"})
