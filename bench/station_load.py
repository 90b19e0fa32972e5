"""The base station under load and under a connection flood, before and after issue 34.

Load: K concurrent `evp stream --realtime` clients (1, 2, 4, 8) of the rendered circle (640x380,
30 fps, JPEG q90: a phone's pace) against one `evp serve`, with SLAM and with the light VO
(klt-vo). Per client: poses per second (the slowest client and the mean) and the latency p95
(worst client); after the fix also how many sessions the station moved to the light VO to keep
every client served (station.full_estimators, one per core).

Flood: 250 slow connections (half stuck in the TLS handshake, half with unfinished headers) and
120 clients that connect and leave, against a station limited to 1024 descriptors; then the time
a phone takes to get its welcome and the operator its state, and the station log's growth.

"before" runs the station from another checkout (--before SRC: its src folder, e.g. the main
branch's); "after" runs this one. The clients are this checkout's either way. Rows alternate
before/after so that other load on the machine affects both alike.

A client whose link is lost (its WebSocket keepalive unanswered for 20 s) counts as 0 poses/s.

Usage: python bench/station_load.py [--before ../main/src] [--duration 10] [--clients 1 2 4 8] [--estimators slam klt-vo] [--skip-flood]
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import json
import os
import resource
import socket
import sqlite3
import ssl
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))  # the station helpers the tests use
from results import Results  # noqa: E402

from tests.station.conftest import free_port, insecure_tls  # noqa: E402

LOAD_COLUMNS = [
    ("station", "{version}"),
    ("estimator", "{estimator}"),
    ("clients", "{clients}"),
    ("poses/s per client (slowest)", "{poses_per_s_min:.1f}"),
    ("poses/s per client (mean)", "{poses_per_s_mean:.1f}"),
    ("latency p95 ms (worst client)", "{latency_ms_p95:.0f}"),
    ("sessions on the light VO", "{degraded}"),
    ("links lost", "{lost}"),
]
FLOOD_COLUMNS = [
    ("station", "{version}"),
    ("phone's welcome s", "{phone_s:.2f}"),
    ("operator's state s", "{operator_s:.2f}"),
    ("slow connections closed", "{slow_closed}/{slow_tls}"),
    ("log growth kB", "{log_kb:.0f}"),
]


class Station:
    """`evp serve` from ``src`` (None: this checkout) on a free port, without credentials."""

    def __init__(self, src: Path | None, data: Path, config: Path | None = None, descriptors: int | None = None):
        self.port = free_port()
        self.data = data
        self.log = data.parent / f"{data.name}.log"
        environment = {**os.environ, "PYTHONPATH": str(src or ROOT / "src")}
        command = [sys.executable, "-m", "evp.cli", "serve", "--host", "127.0.0.1", "--port", str(self.port), "--data", str(data)]
        command += ["--config", str(config)] if config else []
        command += [] if src else ["--dev-loopback"]  # the old station had no credentials at all
        limit = (lambda: resource.setrlimit(resource.RLIMIT_NOFILE, (descriptors, descriptors))) if descriptors else None
        self.process = subprocess.Popen(command, stdout=self.log.open("wb"), stderr=subprocess.STDOUT, env=environment, preexec_fn=limit)
        deadline = time.monotonic() + 90
        while True:
            with contextlib.suppress(OSError), socket.create_connection(("127.0.0.1", self.port), timeout=1):
                break
            if self.process.poll() is not None or time.monotonic() > deadline:
                raise RuntimeError(f"evp serve did not start: {self.log.read_text()[-2000:]}")
            time.sleep(0.2)

    @property
    def url(self) -> str:
        return f"wss://127.0.0.1:{self.port}"

    def stop(self) -> None:
        self.process.terminate()
        try:
            self.process.wait(timeout=60)
        except subprocess.TimeoutExpired:
            self.process.kill()
            self.process.wait()


def _circle(folder: Path, duration: float) -> Path:
    from evp.sim.generate import generate
    from evp.sim.scenarios import SimOptions

    generate("circle-indoor", SimOptions(duration_s=duration, fps=30.0, seed=1), folder, workers=1)
    return folder


def _client(url: str, source: str) -> None:
    """One client (run as its own process): streams at the source's pace, prints its poses per
    second between its first and last pose (connection and estimator start-up excluded) and its
    latency p95."""
    from evp.mobile.client import StreamClient
    from evp.mobile.sources import open_source

    received: list[float] = []
    client = StreamClient(url, insecure=True, on_pose=lambda pose: received.append(time.monotonic()), log=lambda text: None)  # loopback, its own station
    report = asyncio.run(client.run(open_source(source, None, None), True, "jpeg", 90))
    rate = (len(received) - 1) / (received[-1] - received[0]) if len(received) > 2 else 0.0
    print(json.dumps({"poses_per_s": rate, "latency_ms_p95": report.summary()["latency_ms_p95"]}))


def _summary(process: subprocess.Popen) -> dict:
    """A client's figures; a client whose link was lost counts as 0 poses/s."""
    out, err = process.communicate(timeout=900)
    if process.returncode != 0:
        print(f"  a client failed: {err.strip().splitlines()[-1:]}", file=sys.stderr)
        return {"poses_per_s": 0.0, "latency_ms_p95": None, "lost": True}
    return {**json.loads(out.strip().splitlines()[-1]), "lost": False}


def _load(version: str, src: Path | None, estimator: str, clients: int, source: Path, work: Path) -> dict:
    config = work / f"{estimator}.yaml"
    config.write_text(f"estimator: {estimator}\n")
    data = work / f"load-{version}-{estimator}-{clients}"
    station = Station(src, data, config)
    try:
        time.sleep(1.0)
        command = [sys.executable, __file__, "--client", station.url, str(source)]
        environment = {**os.environ, "PYTHONPATH": str(ROOT / "src")}
        processes = [subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=environment) for _ in range(clients)]
        summaries = [_summary(p) for p in processes]
    finally:
        station.stop()
    rates = [s["poses_per_s"] for s in summaries]
    with contextlib.closing(sqlite3.connect(data / "evp.sqlite")) as database:
        degraded = database.execute("SELECT COUNT(DISTINCT session_id) FROM events WHERE code = 'degraded'").fetchone()[0]
    return {
        "version": version,
        "estimator": estimator,
        "clients": clients,
        "poses_per_s_min": min(rates),
        "poses_per_s_mean": sum(rates) / len(rates),
        "latency_ms_p95": max((s["latency_ms_p95"] for s in summaries if not s["lost"]), default=None),
        "lost": sum(s["lost"] for s in summaries),
        "degraded": degraded,
    }


async def _flood_scenario(station: Station) -> tuple[float, float, int, int]:
    from evp.station.protocol import PROTOCOL_VERSION, Hello, encode

    slow = []
    for k in range(250):
        raw = await asyncio.to_thread(socket.create_connection, ("127.0.0.1", station.port))
        wrapped = None
        if k % 2 == 0:
            wrapped = await asyncio.to_thread(insecure_tls().wrap_socket, raw, server_hostname="127.0.0.1")
            wrapped.sendall(b"GET / HTTP/1.1\r\nHost: 127.0.0.1\r\n")
        slow.append((raw, wrapped))

    async def connect_and_leave() -> None:
        for _ in range(120):
            with contextlib.suppress(OSError):
                (await asyncio.to_thread(socket.create_connection, ("127.0.0.1", station.port))).close()

    import websockets

    leaving = asyncio.create_task(connect_and_leave())
    start = time.monotonic()
    async with websockets.connect(f"{station.url}/ws/mobile", ssl=insecure_tls(), open_timeout=60) as phone:
        await phone.send(encode(Hello(protocol=PROTOCOL_VERSION, device="phone")))
        while json.loads(await asyncio.wait_for(phone.recv(), 60))["type"] != "welcome":
            pass
        phone_s = time.monotonic() - start
    start = time.monotonic()
    await asyncio.to_thread(_get_state, station.port)
    operator_s = time.monotonic() - start
    await leaving
    await asyncio.sleep(12.0)  # past the default header timeout (10 s)
    closed = 0
    for raw, wrapped in slow:
        if wrapped is not None:
            wrapped.settimeout(0.2)
            with contextlib.suppress(OSError):
                closed += wrapped.recv(1) == b""
        raw.close()
    return phone_s, operator_s, closed, sum(1 for _, w in slow if w is not None)


def _get_state(port: int) -> None:
    context = ssl.SSLContext(ssl.PROTOCOL_TLS_CLIENT)
    context.check_hostname, context.verify_mode = False, ssl.CERT_NONE
    with socket.create_connection(("127.0.0.1", port), timeout=60) as raw, context.wrap_socket(raw, server_hostname="127.0.0.1") as connection:
        connection.sendall(b"GET /api/state HTTP/1.1\r\nHost: 127.0.0.1\r\nConnection: close\r\n\r\n")
        assert connection.recv(64).startswith(b"HTTP/1.1 200"), "the operator's state"


def _flood(version: str, src: Path | None, work: Path) -> dict:
    station = Station(src, work / f"flood-{version}", descriptors=1024)
    try:
        size = station.log.stat().st_size
        phone_s, operator_s, closed, tls = asyncio.run(_flood_scenario(station))
        log_kb = (station.log.stat().st_size - size) / 1000
    finally:
        station.stop()
    return {"version": version, "phone_s": phone_s, "operator_s": operator_s, "slow_closed": closed, "slow_tls": tls, "log_kb": log_kb}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--before", type=Path, help="src folder of the station to compare with (e.g. the main branch's checkout)/src")
    parser.add_argument("--duration", type=float, default=10.0, help="seconds of 30 fps video per client")
    parser.add_argument("--clients", type=int, nargs="+", default=[1, 2, 4, 8])
    parser.add_argument("--estimators", nargs="+", default=["slam", "klt-vo"])
    parser.add_argument("--skip-flood", action="store_true")
    parser.add_argument("--client", nargs=2, metavar=("URL", "SOURCE"), help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.client:
        _client(*args.client)
        return
    command = f"python bench/station_load.py {' '.join(sys.argv[1:])}".rstrip()
    print(f"command: {command}")
    results = Results("station_load", command)
    versions = ([("before", args.before.resolve())] if args.before else []) + [("after", None)]
    caption = "Loopback, TLS, rendered circle 640x380 at 30 fps, JPEG q90; the station and its clients share the machine's 2 cores"
    load = results.table("load", LOAD_COLUMNS, key=["version", "estimator", "clients"], caption=caption)
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        source = _circle(work / "circle", args.duration)
        print(load.header())
        for estimator in args.estimators:
            for clients in args.clients:
                for version, src in versions:
                    print(load.add(_load(version, src, estimator, clients, source, work)), flush=True)
        if not args.skip_flood:
            flood = results.table(
                "flood", FLOOD_COLUMNS, key=["version"], caption="250 slow and 120 connect-and-leave clients, station limited to 1024 descriptors"
            )
            print(flood.header())
            for version, src in versions:
                print(flood.add(_flood(version, src, work)), flush=True)


if __name__ == "__main__":
    main()
