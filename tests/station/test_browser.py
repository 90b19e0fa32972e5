"""The operator UI and the phone page in a real headless Chromium (Debian's), driven by Playwright.

The phone page gets a fake camera playing a video made from the bundled sample and an overridden
geolocation; the operator sets the sample's camera in the camera dialog, presses Configure, and
must then see the trajectory and the event log. Screenshots land in test-artifacts/.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest

from evp.io.registry import open_dataset
from evp.station.store import SessionStore
from tests.conftest import PROJECT, SAMPLE
from tests.station.conftest import operator_login_code, running_station, station_database

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
ARTIFACTS = PROJECT / "test-artifacts"


def write_y4m(path: Path, images: list[np.ndarray], fps: int) -> None:
    """A raw YUV 4:2:0 video, the format Chromium's fake camera plays."""
    height, width = images[0].shape[:2]
    with path.open("wb") as handle:
        handle.write(f"YUV4MPEG2 W{width} H{height} F{fps}:1 Ip A1:1 C420jpeg\n".encode())
        for image in images:
            bgr = image if image.ndim == 3 else cv2.cvtColor(image, cv2.COLOR_GRAY2BGR)
            handle.write(b"FRAME\n" + cv2.cvtColor(bgr, cv2.COLOR_BGR2YUV_I420).tobytes())


def wait_on_phone(phone, station, expression: str, timeout: float = 30_000) -> None:
    """``phone.wait_for_function`` that, when it times out, fails with what the phone page logged
    and the end of the station's log: a link refused (storage_full, bad_token) or a station that
    stopped answering says so, rather than only that 30 s passed."""
    sync_api = pytest.importorskip("playwright.sync_api")
    try:
        phone.wait_for_function(expression, timeout=timeout)
    except sync_api.TimeoutError:
        page_log = phone.inner_text("#log")
        serve_log = (station.data.parent / f"{station.data.name}-serve.log").read_text(errors="replace")[-3000:]
        pytest.fail(f"phone page: {expression} not true within {timeout / 1000:.0f} s\nphone log:\n{page_log}\nstation log (end):\n{serve_log}")


@pytest.mark.skipif(CHROMIUM is None, reason="Debian's chromium is not installed (scripts/test.sh installs it when it can)")
def test_phone_page_streams_and_operator_sees_the_trajectory(tmp_path, station_data):
    sync_api = pytest.importorskip("playwright.sync_api")
    dataset = open_dataset(SAMPLE)
    camera = dataset.camera
    video = tmp_path / "sample.y4m"
    # played at a rate a loaded 2-core runner keeps up with beside the browser: this test is about
    # the pages and the link; tracking through dropped frames is measured on its own
    fps = 5
    write_y4m(video, [frame.image for frame in dataset.frames()], fps=fps)
    ARTIFACTS.mkdir(exist_ok=True)
    args = ["--use-fake-ui-for-media-stream", "--use-fake-device-for-media-stream", f"--use-file-for-fake-video-capture={video}", "--no-sandbox"]
    with running_station(station_data, paired=True) as station, sync_api.sync_playwright() as playwright:
        browser = playwright.chromium.launch(executable_path=CHROMIUM, args=args)
        context = browser.new_context(ignore_https_errors=True, geolocation={"latitude": 3.3745, "longitude": -76.5331}, permissions=["geolocation"])
        stranger = context.new_page()
        stranger.goto(f"{station.http}/")  # not logged in: the page says how
        stranger.wait_for_function("document.getElementById('st-link').textContent.startsWith('not logged in')")
        operator = context.new_page()
        operator.goto(f"{station.http}/#pair={operator_login_code(station)}")  # the login link evp serve prints
        operator.wait_for_function("document.getElementById('st-link').textContent === 'up'")
        assert "#pair" not in operator.url  # the used code left the address bar
        operator.click("#camera-button")
        form = "#camera-form"
        for name in ("width", "height", "fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3"):
            operator.fill(f"{form} [name={name}]", str(getattr(camera, name)))
        operator.fill(f"{form} [name=fps]", str(fps))
        operator.click(f"{form} button[value=ok]")
        operator.click("#configure")
        operator.wait_for_function("document.getElementById('configure-result').textContent.startsWith('stored')")

        operator.click("#pair-phone")  # a one-time QR code for the phone
        operator.wait_for_function("window.evp.pairingUrl !== undefined")
        phone = context.new_page()
        phone.goto(operator.evaluate("window.evp.pairingUrl"))  # what scanning the QR code opens
        wait_on_phone(phone, station, "localStorage.getItem('evp.credential') !== null")
        wait_on_phone(phone, station, "document.getElementById('link').textContent.startsWith('ready')")
        phone.click("#start")  # the link opens now; the station's config (the operator's camera) comes with it
        wait_on_phone(phone, station, "window.evpPhone.config && window.evpPhone.config.camera.width === 240")
        wait_on_phone(phone, station, "window.evpPhone.sensing === true")
        phone.evaluate(  # a headless browser has no motion sensors: 12 readings as the phone's would come
            """() => { for (let k = 0; k < 12; k++) window.dispatchEvent(new DeviceMotionEvent("devicemotion", {
                 accelerationIncludingGravity: {x: 0, y: 0, z: 9.8}, rotationRate: {alpha: 1, beta: 2, gamma: 3}, interval: 16})); }"""
        )
        wait_on_phone(phone, station, "window.evpPhone.poses >= 40 && window.evpPhone.gps >= 1 && window.evpPhone.imu === 12", timeout=120_000)
        operator.wait_for_function(
            "(() => { const s = window.evp.selected; return s && window.evp.trajectories[s] && window.evp.trajectories[s].points.filter(p => p.state === 'OK').length >= 10; })()",
            timeout=60_000,
        )
        # the status bar fills on the station's next status tick (each second)
        operator.wait_for_function("document.getElementById('st-state').textContent === 'running'", timeout=10_000)
        phone.screenshot(path=str(ARTIFACTS / "phone_page.png"), full_page=True)
        operator.screenshot(path=str(ARTIFACTS / "operator_ui.png"), full_page=True)
        log_text = operator.inner_text("#event-log")
        assert "[connected]" in log_text and "[estimator_ready]" in log_text and "[configure]" in log_text
        assert operator.inner_text("#st-comm") == "connected" and operator.inner_text("#st-state") == "running"
        # the fake camera loops the clip, so tracking is lost and regained: wait for an OK pose on screen
        operator.wait_for_function("/ OK /.test(document.getElementById('pose').textContent)", timeout=60_000)
        assert " OK " in operator.inner_text("#pose")
        session_id = operator.evaluate("window.evp.selected")
        phone.uncheck("#enable")
        operator.wait_for_function("document.getElementById('st-state').textContent === 'stopped'", timeout=10_000)
        browser.close()
    store = SessionStore(station_database(station_data))
    try:
        rows = store.rows("telemetry", session_id)
        assert "gps" in {row["kind"] for row in rows}
        imu = [json.loads(row["data_json"])["samples"] for row in rows if row["kind"] == "imu"]
        assert sum(len(samples) for samples in imu) == 12  # sent together (before frames), every reading kept
        assert "disable" in [e["code"] for e in store.rows("events", session_id)]
        assert len(store.rows("poses", session_id)) >= 40
    finally:
        store.close()


@pytest.mark.skipif(CHROMIUM is None, reason="Debian's chromium is not installed (scripts/test.sh installs it when it can)")
def test_operator_page_shows_the_gps_alignment_the_trust_change_and_the_alarm(station_data):
    """The operator page fed the messages a station sends during a flight (the station's side of
    them is tested in tests/station/test_faults.py and tests/runtime): the alignment phase, GPS
    trusted with the fused track against GPS, the spoofing alarm as GPS is pulled off; and a
    long session's 20000 poses kept to a couple of thousand points."""
    sync_api = pytest.importorskip("playwright.sync_api")
    sid = "20260101-000000-flight"

    def pose(k: int, gps: str, georeferenced: bool) -> dict:
        east = 0.5 * k
        return {
            "seq": k, "timestamp": k / 30.0, "t": [east, 0.0, 60.0], "q": [1, 0, 0, 0], "state": "OK", "quality": 90, "metric": True,
            "georeferenced": georeferenced, "gps_trusted": gps == "trusted", "gps": gps, "visual_age_s": 0.05,
            "latitude_deg": 43.7238 if georeferenced else None, "longitude_deg": 10.3966 + east / 80500.0 if georeferenced else None,
            "altitude_m": 64.0 if georeferenced else None,
        }  # fmt: skip

    def feed(page, *messages) -> None:
        for message in messages:
            page.evaluate("m => onMessage(m)", message)

    alignment = {"pairs": 12, "spread_m": 8.0, "needed_m": 20.0, "model": None, "residual_m": None}
    with running_station(station_data) as station, sync_api.sync_playwright() as playwright:
        browser = playwright.chromium.launch(executable_path=CHROMIUM, args=["--no-sandbox"])
        page = browser.new_context(ignore_https_errors=True).new_page()
        page.goto(station.http)
        # the station's snapshot (its live sessions: none) must be in before the messages fed here,
        # or, arriving after them on a loaded machine, it unselects their session
        page.wait_for_function("document.getElementById('st-link').textContent === 'up' && document.getElementById('db').textContent !== ''")
        navigation = {"status": "initialised", "running": True, "gps": "aligning", "alignment": alignment, "sensors": ["imu", "gps"]}
        feed(page, {"type": "navigation", "session_id": sid, "navigation": navigation}, {"type": "pose", "session_id": sid, "pose": pose(0, "aligning", False)})
        banner = page.locator("#nav-banner")
        assert "GPS alignment: 12 fixes, spread 8.0 of 20 m" in banner.inner_text()
        fitted = {
            **navigation,
            "gps": "trusted",
            "alignment": {**alignment, "pairs": 30, "spread_m": 20.5, "model": "heading + translation", "residual_m": 1.2},
        }
        feed(page, {"type": "navigation", "session_id": sid, "navigation": fitted})
        for k in range(1, 60):
            fix = {"timestamp": k / 30.0, "latitude_deg": 43.7238 + 1e-6 * (k % 3), "longitude_deg": 10.3966 + 0.5 * k / 80500.0}
            feed(page, {"type": "gps", "session_id": sid, "fix": fix}, {"type": "pose", "session_id": sid, "pose": pose(k, "trusted", True)})
        page.wait_for_function("document.getElementById('nav-banner').dataset.gps === 'trusted'")
        assert banner.get_attribute("class") == "banner ok" and "residual 1.20 m" in banner.inner_text()
        page.screenshot(path=str(ARTIFACTS / "operator_gps_trusted.png"), full_page=True)
        alarm = {"session_id": sid, "t": 1.7e9, "level": "warning", "code": "spoofing_alarm", "text": "GPS at 62.0 s: GPS disagrees with vision by 9 m"}
        feed(page, {"type": "event", "event": alarm}, {"type": "pose", "session_id": sid, "pose": pose(60, "untrusted", True)})
        assert banner.get_attribute("class") == "banner alarm" and "SPOOFING" in banner.inner_text()
        assert "[spoofing_alarm]" in page.inner_text("#event-log")
        page.screenshot(path=str(ARTIFACTS / "operator_spoofing_alarm.png"), full_page=True)
        kept = page.evaluate(
            """sid => { for (let k = 61; k < 20061; k++) onMessage({type: "pose", session_id: sid, pose: Object.assign({}, window.evp.trajectories[sid].last, {seq: k, timestamp: k / 30})});
                        return window.evp.trajectories[sid].points.length; }""",
            sid,
        )
        assert 1000 <= kept <= 2001
        browser.close()
