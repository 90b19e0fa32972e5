"""A real ``evp serve`` in a subprocess on a free loopback port, and helpers to talk to it."""

from __future__ import annotations

import contextlib
import json
import signal
import socket
import ssl
import subprocess
import sys
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest


def free_port(kind: int = socket.SOCK_STREAM) -> int:
    with socket.socket(socket.AF_INET, kind) as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


@dataclass
class RunningStation:
    process: subprocess.Popen
    port: int
    data: Path

    @property
    def url(self) -> str:
        return f"wss://127.0.0.1:{self.port}"

    @property
    def http(self) -> str:
        return f"https://127.0.0.1:{self.port}"

    def stop(self, sig: int = signal.SIGTERM) -> None:
        if self.process.poll() is None:
            self.process.send_signal(sig)
            try:
                self.process.wait(timeout=60)
            except subprocess.TimeoutExpired:
                self.process.kill()
                self.process.wait()


@contextlib.contextmanager
def running_station(data: Path, *options: str, port: int | None = None) -> Iterator[RunningStation]:
    port = port or free_port()
    log = (data.parent / f"{data.name}-serve.log").open("ab")
    command = [sys.executable, "-m", "evp.cli", "serve", "--host", "127.0.0.1", "--port", str(port), "--data", str(data), *options]
    process = subprocess.Popen(command, stdout=log, stderr=subprocess.STDOUT)
    station = RunningStation(process, port, data)
    try:
        deadline = time.monotonic() + 60
        while True:
            if process.poll() is not None:
                raise RuntimeError(f"evp serve exited with {process.returncode}: {(data.parent / f'{data.name}-serve.log').read_text()}")
            with contextlib.suppress(OSError), socket.create_connection(("127.0.0.1", port), timeout=1):
                break
            if time.monotonic() > deadline:
                raise RuntimeError("evp serve did not start listening within 60 s")
            time.sleep(0.2)
        yield station
    finally:
        station.stop()
        log.close()


def insecure_tls() -> ssl.SSLContext:
    context = ssl.SSLContext(ssl.PROTOCOL_TLS_CLIENT)
    context.check_hostname = False
    context.verify_mode = ssl.CERT_NONE
    return context


def run_stream(*args: str, timeout: float = 300) -> dict:
    """``evp stream`` as a user runs it; returns its last line (the JSON summary)."""
    result = subprocess.run([sys.executable, "-m", "evp.cli", "stream", *args], capture_output=True, text=True, timeout=timeout)
    assert result.returncode == 0, result.stderr + result.stdout
    return json.loads(result.stdout.strip().splitlines()[-1])


@pytest.fixture
def station_data(tmp_path) -> Path:
    return tmp_path / "station"
