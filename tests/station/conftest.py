"""A real ``evp serve`` in a subprocess on a free loopback port, and helpers to talk to it."""

from __future__ import annotations

import asyncio
import contextlib
import json
import signal
import socket
import ssl
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest
import websockets


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


class OperatorFeed:
    """The station's live feed to operator pages (``/ws/operator``), read on a thread, so that a
    test waits for what the station announces (a session ended, interrupted, released) instead of
    sleeping. Everything received since connecting is kept; waits look at all of it."""

    def __init__(self, station: RunningStation, token: str = ""):
        self.url = f"{station.url}/ws/operator" + (f"?token={token}" if token else "")
        self.messages: list[dict] = []
        self._arrived = threading.Condition()
        self._loop = asyncio.new_event_loop()
        self._reader: asyncio.Task | None = None
        self._thread = threading.Thread(target=self._run, name="operator-feed", daemon=True)
        self._failure: BaseException | None = None
        self._closed = False

    def __enter__(self) -> OperatorFeed:
        self._thread.start()
        self.wait_for(lambda m: m["type"] == "snapshot", 30, "its snapshot")  # sent once this feed is registered
        return self

    def __exit__(self, *exc) -> None:
        with contextlib.suppress(RuntimeError):  # the station may have closed the feed already (its loop is closed)
            self._loop.call_soon_threadsafe(self._reader.cancel)
        self._thread.join(timeout=10)

    def _run(self) -> None:
        async def read() -> None:
            async with websockets.connect(self.url, ssl=insecure_tls()) as connection:
                async for text in connection:
                    with self._arrived:
                        self.messages.append(json.loads(text))
                        self._arrived.notify_all()

        try:
            self._reader = self._loop.create_task(read())
            self._loop.run_until_complete(self._reader)
        except (asyncio.CancelledError, websockets.ConnectionClosed):
            pass
        except BaseException as exc:  # a refused or broken feed fails the waiting test, not silently
            self._failure = exc
        finally:
            with self._arrived:
                self._closed = True
                self._arrived.notify_all()
            self._loop.close()

    def wait_for(self, predicate: Callable[[dict], bool], timeout: float, what: str) -> dict:
        """The first message (received before or after this call) that ``predicate`` accepts."""

        def found() -> dict | None:
            return next((m for m in self.messages if predicate(m)), None)

        with self._arrived:
            self._arrived.wait_for(lambda: found() is not None or self._closed, timeout)
            message = found()
        if message is None:
            state = f"the feed closed ({self._failure!r})" if self._closed else f"within {timeout:g} s"
            raise AssertionError(f"the station did not announce {what}: {state}")
        return message

    def event(self, code: str, session_id: str | None = None, timeout: float = 60) -> dict:
        """The station's event ``code`` (of ``session_id`` when given): it is logged and broadcast together."""

        def matches(m: dict) -> bool:
            return m["type"] == "event" and m["event"]["code"] == code and session_id in (None, m["event"]["session_id"])

        return self.wait_for(matches, timeout, f"event {code!r}" + (f" of session {session_id}" if session_id else ""))["event"]


def committed(check: Callable[[], bool], what: str, timeout: float = 20) -> None:
    """Wait until the station's database shows ``check``. The station queues its writes and one
    thread commits them (``evp.station.store``); nothing announces a commit, so this is the one
    wait that reads until the rows are there (a commit takes milliseconds after the event)."""
    deadline = time.monotonic() + timeout
    while not check():
        assert time.monotonic() < deadline, f"the station did not commit {what} within {timeout:g} s"
        time.sleep(0.02)


def indexed_messages(path) -> list[tuple[str, int, object]]:
    """(topic, log time, decoded message) of a finished recording, read with the ``mcap`` library's
    indexed reader: the file must be chunked, zstd-compressed and indexed (what Foxglove seeks in)."""
    from mcap.reader import make_reader

    from evp.io.ros_messages import ROS2

    with Path(path).open("rb") as handle:
        reader = make_reader(handle)
        summary = reader.get_summary()
        assert summary is not None and summary.chunk_indexes, f"{path}: no chunk index"
        assert all(c.compression == "zstd" and c.message_index_offsets for c in summary.chunk_indexes), f"{path}: chunks not compressed or indexed"
        messages = [(channel.topic, message.log_time, ROS2.deserialize_cdr(message.data, schema.name)) for schema, channel, message in reader.iter_messages()]
    assert len(messages) == summary.statistics.message_count
    return messages


def run_stream(*args: str, timeout: float = 300) -> dict:
    """``evp stream`` as a user runs it; returns its last line (the JSON summary)."""
    result = subprocess.run([sys.executable, "-m", "evp.cli", "stream", *args], capture_output=True, text=True, timeout=timeout)
    assert result.returncode == 0, result.stderr + result.stdout
    return json.loads(result.stdout.strip().splitlines()[-1])


@pytest.fixture
def station_data(tmp_path) -> Path:
    return tmp_path / "station"
