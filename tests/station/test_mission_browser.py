"""The operator's mission page in a real headless Chromium: it shows the marker map growing and
the state, and a command pressed there lands the simulated vehicle (seed 003's monitoring station)."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
import time
import urllib.request

import pytest

from tests.conftest import PROJECT
from tests.station.conftest import free_port

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
ARTIFACTS = PROJECT / "test-artifacts"


def _wait_for_page(url: str, process: subprocess.Popen, seconds: float = 60.0) -> None:
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline:
        if process.poll() is not None:
            raise AssertionError(f"evp fly --serve ended early: {process.stderr.read()}")
        try:
            urllib.request.urlopen(url, timeout=1).read()
            return
        except OSError:
            time.sleep(0.2)
    raise AssertionError("the mission page never came up")


@pytest.mark.skipif(CHROMIUM is None, reason="Debian's chromium is not installed (scripts/test.sh installs it when it can)")
def test_a_land_command_from_the_mission_page_lands_the_simulated_vehicle(tmp_path):
    sync_api = pytest.importorskip("playwright.sync_api")
    port = free_port()
    out = tmp_path / "mission"
    command = [sys.executable, "-m", "evp.cli", "fly", "marker-field", "--serve", str(port), "--hover", "120", "--duration", "60"]
    command += ["--resolution", "240x180", "--linger", "2", "--out", str(out)]
    process = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        url = f"http://127.0.0.1:{port}/"
        _wait_for_page(url, process)
        with sync_api.sync_playwright() as playwright:
            browser = playwright.chromium.launch(executable_path=CHROMIUM, args=["--no-sandbox"])
            page = browser.new_page()
            page.goto(url)
            page.wait_for_function("document.getElementById('state').textContent === 'exploration'", timeout=60_000)
            page.wait_for_function("parseInt(document.getElementById('mapped').textContent) >= 4", timeout=30_000)
            page.fill("#marker-id", "97")  # not mapped yet: refused
            page.click("#land-on")
            page.wait_for_function("document.getElementById('command-result').textContent.includes('refused')", timeout=10_000)
            page.click("#land")
            page.wait_for_function("document.getElementById('state').textContent === 'landed'", timeout=30_000)
            ARTIFACTS.mkdir(exist_ok=True)
            page.screenshot(path=str(ARTIFACTS / "mission_page.png"))
            browser.close()
        process.wait(timeout=60)
    finally:
        if process.poll() is None:
            process.kill()
    assert process.returncode == 0, process.stderr.read()
    mission = json.loads((out / "mission.json").read_text())
    assert mission["landed"] and not mission["left_room"] and mission["mission_time_s"] < 60
    events = json.loads((out / "events.json").read_text())
    assert any(e["kind"] == "command" and e["detail"] == "land" for e in events)
    assert any(e["kind"] == "command_rejected" and "97" in e["detail"] for e in events)
