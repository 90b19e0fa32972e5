"""The operator page as a new user meets it, in a real headless Chromium: no session appears
until a phone streams, the recorded-session counts follow the status bar while a session runs,
the state says "ended" once it ends, the plots have real axes and the top view a scale bar; and
the phone page keeps its frames in order on a throttled CPU (Chrome DevTools' CPU throttling)."""

from __future__ import annotations

import json
import subprocess
import sys
import urllib.request

import pytest

from tests.conftest import SAMPLE
from tests.station.conftest import insecure_tls, running_station, station_database
from tests.station.test_browser import ARTIFACTS, CHROMIUM, write_y4m

pytestmark = pytest.mark.skipif(CHROMIUM is None, reason="Debian's chromium is not installed (scripts/test.sh installs it when it can)")

ROW_MATCHES_STATUS_BAR = """sid => {
  const row = document.querySelector(`#sessions tbody tr[data-session="${sid}"]`), live = window.evp.live[sid];
  return row && live && live.status && live.status.frames_received > 0
    && Number(row.cells[3].textContent) === live.status.frames_received
    && document.getElementById('st-frames').textContent.startsWith(live.status.frames_received + ' received');
}"""


def _sessions(station) -> list[dict]:
    with urllib.request.urlopen(f"{station.http}/api/sessions", context=insecure_tls()) as response:
        return json.loads(response.read())["sessions"]


def test_operator_counts_and_states_follow_a_session(station_data):
    sync_api = pytest.importorskip("playwright.sync_api")
    with running_station(station_data) as station, sync_api.sync_playwright() as playwright:
        browser = playwright.chromium.launch(executable_path=CHROMIUM, args=["--no-sandbox"])
        context = browser.new_context(ignore_https_errors=True)
        operator = context.new_page()
        operator.goto(station.http)
        operator.wait_for_function("document.getElementById('st-link').textContent === 'up'")
        phone = context.new_page()  # opened, never started: no session, no recording
        phone.goto(f"{station.http}/phone")
        phone.wait_for_function("document.getElementById('link').textContent.startsWith('ready')")
        assert _sessions(station) == [] and not list(station_data.glob("**/*.mcap"))
        assert operator.inner_text("#st-state") == "idle"

        stream = subprocess.Popen(
            [
                sys.executable,
                "-m",
                "evp.cli",
                "stream",
                str(SAMPLE),
                "--url",
                station.url,
                "--cafile",
                str(station_data / "tls" / "cert.pem"),
                "--quiet",
                "--realtime",
                "--max-frames",
                "60",
            ],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        try:
            operator.wait_for_function("window.evp.selected !== null", timeout=60_000)
            sid = operator.evaluate("window.evp.selected")
            # while it streams, the table's count is the status bar's (both from the live status)
            operator.wait_for_function(ROW_MATCHES_STATUS_BAR, arg=sid, timeout=60_000)
            assert operator.inner_text("#st-state") in ("starting", "running")
            assert stream.wait(timeout=120) == 0, stream.stderr.read()
        finally:
            if stream.poll() is None:
                stream.kill()
                stream.wait()
        operator.wait_for_function("document.getElementById('st-state').textContent === 'ended'", timeout=30_000)
        operator.wait_for_function(
            "sid => { const row = document.querySelector(`#sessions tbody tr[data-session=\"${sid}\"]`); return row && row.cells[2].textContent === 'ended'; }",
            arg=sid,
            timeout=30_000,
        )
        assert operator.inner_text("#st-fps") == "0"
        top = operator.locator("#top-view")
        assert int(top.get_attribute("data-xticks")) >= 3 and int(top.get_attribute("data-yticks")) >= 3
        assert top.get_attribute("data-scale-bar").endswith("map units")
        ARTIFACTS.mkdir(exist_ok=True)
        operator.screenshot(path=str(ARTIFACTS / "operator_session_ended.png"), full_page=True)
        browser.close()
    rows = {row["id"]: row for row in _sessions_after(station_data)}
    assert rows[sid]["status"] == "ended" and rows[sid]["frames_received"] == 60


def _sessions_after(station_data) -> list[dict]:
    from evp.station.store import SessionStore

    store = SessionStore(station_database(station_data))
    try:
        return store.list_sessions(limit=None)
    finally:
        store.close()


def test_phone_frames_stay_in_order_on_a_throttled_cpu(tmp_path, station_data):
    """The phone encodes frames asynchronously; under a 6x slower CPU two encodings finish out of
    order, and frames numbered on completion reached the station out of order (refused)."""
    sync_api = pytest.importorskip("playwright.sync_api")
    from evp.io.registry import open_dataset

    video = tmp_path / "sample.y4m"
    write_y4m(video, [frame.image for frame in open_dataset(SAMPLE).frames()], fps=30)
    args = ["--use-fake-ui-for-media-stream", "--use-fake-device-for-media-stream", f"--use-file-for-fake-video-capture={video}", "--no-sandbox"]
    with running_station(station_data) as station, sync_api.sync_playwright() as playwright:
        browser = playwright.chromium.launch(executable_path=CHROMIUM, args=args)
        phone = browser.new_context(ignore_https_errors=True).new_page()
        phone.context.new_cdp_session(phone).send("Emulation.setCPUThrottlingRate", {"rate": 6})
        phone.goto(f"{station.http}/phone")
        phone.wait_for_function("document.getElementById('link').textContent.startsWith('ready')", timeout=60_000)
        phone.click("#start")
        phone.wait_for_function("window.evpPhone.sessionId !== null", timeout=60_000)
        phone.uncheck("#enable")  # the station records without estimating: the link is what is tested
        phone.wait_for_function("window.evpPhone.sent >= 60", timeout=120_000)
        counts = phone.evaluate("({sent: window.evpPhone.sent, errors: window.evpPhone.errors, skipped: window.evpPhone.skipped})")
        log = phone.inner_text("#log")
        browser.close()
    assert counts["errors"] == 0, log


BACKGROUND_ROW_COLOURS = """() => {
  const canvas = document.getElementById('top-view'), ctx = canvas.getContext('2d');
  const left = PLOT.left, right = canvas.width - PLOT.right, middle = Math.round((left + right) / 2);
  const row = Math.round(PLOT.top + (canvas.height - PLOT.top - PLOT.bottom) / 2);
  const red = (x0, x1) => { let n = 0; for (let x = x0; x < x1; x++) { const [r, g, b] = ctx.getImageData(x, row, 1, 1).data; n += r > 200 && g < 120 && b < 120; } return n / (x1 - x0); };
  return [canvas.dataset.background, red(left, middle), red(middle, right)];
}"""


def test_an_orthophoto_lies_under_the_georeferenced_top_view_where_its_bounds_say(tmp_path, station_data):
    """The station's background image (a red west half of a 110 m square) is drawn under a
    georeferenced track around that square, north up: red west of the square's centre, none east."""
    sync_api = pytest.importorskip("playwright.sync_api")
    import cv2
    import numpy as np
    import yaml

    lat, lon, d = 47.0, 8.0, 0.0005
    image = tmp_path / "ortho.png"
    cv2.imwrite(str(image), np.dstack([np.zeros((64, 64), np.uint8), np.zeros((64, 64), np.uint8), np.full((64, 64), 255, np.uint8)]))
    config = tmp_path / "station.yaml"
    config.write_text(yaml.safe_dump({"station": {"background_image": str(image), "background_bounds_deg": [lat - d, lon - d, lat + d, lon]}}))
    corners = [(lat - d, lon - d), (lat - d, lon + d), (lat + d, lon + d), (lat + d, lon - d), (lat - d, lon - d)]
    poses = [
        {"t": [0, 0, 30], "state": "OK", "metric": True, "timestamp": k, "latitude_deg": a, "longitude_deg": o, "altitude_m": 30.0}
        for k, (a, o) in enumerate(corners)
    ]
    with running_station(station_data, "--config", str(config)) as station, sync_api.sync_playwright() as playwright:
        browser = playwright.chromium.launch(executable_path=CHROMIUM, args=["--no-sandbox"])
        operator = browser.new_context(ignore_https_errors=True).new_page()
        operator.goto(station.http)
        operator.wait_for_function("window.evp.background !== null")
        operator.evaluate("poses => { evp.selected = 's'; for (const pose of poses) series(evp.trajectories, 's').push(pose); redraw(); }", poses)
        drawn, west, east = operator.evaluate(BACKGROUND_ROW_COLOURS)
        operator.screenshot(path=str(ARTIFACTS / "operator-background.png"))
        browser.close()
    assert drawn == "drawn" and west > 0.3 and east < 0.02, (west, east)
