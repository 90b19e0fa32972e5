"""A real ``evp serve`` in a subprocess on a free loopback port, and helpers to talk to it.

Stations run in the development mode (``--dev-loopback``: no credentials) unless a test asks for
``paired=True``; then ``operator_credential`` and ``mobile_credential`` pair as a real operator
and phone do (a one-time code for a credential).

Each station keeps its database in its data folder (SQLite) unless ``EVP_TEST_POSTGRES`` names a
PostgreSQL server (``postgresql://user@host:port/db``, e.g. what ``scripts/postgres.sh start``
prints): then each data folder gets a database of its own there, and the station suite runs on
PostgreSQL (too long to run twice in CI: docs/station.md says how to run it)."""

from __future__ import annotations

import asyncio
import contextlib
import hashlib
import json
import os
import shutil
import signal
import socket
import ssl
import subprocess
import sys
import tempfile
import threading
import time
import urllib.error
import urllib.request
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest
import websockets


def free_port(kind: int = socket.SOCK_STREAM) -> int:
    with socket.socket(socket.AF_INET, kind) as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


def new_postgres_database(server: str, name: str | None = None) -> str:
    """The URL of a new, empty database on the PostgreSQL ``server`` (a fresh name unless given)."""
    import uuid

    import sqlalchemy as sa

    from evp.station.schema import open_engine

    name = name or f"t{uuid.uuid4().hex[:12]}"
    admin = open_engine(server)
    with admin.connect().execution_options(isolation_level="AUTOCOMMIT") as connection:
        connection.execute(sa.text(f"CREATE DATABASE {name}"))
    admin.dispose()
    return server.rpartition("/")[0] + f"/{name}"


_POSTGRES_DATABASES: dict[Path, str] = {}


def station_database(data: Path) -> str:
    """The database URL of the station whose data folder is ``data``: its SQLite file, or its own
    database on the ``EVP_TEST_POSTGRES`` server."""
    server = os.environ.get("EVP_TEST_POSTGRES")
    if not server:
        return f"sqlite:///{data / 'evp.sqlite'}"
    data = data.resolve()
    if data not in _POSTGRES_DATABASES:
        _POSTGRES_DATABASES[data] = new_postgres_database(server, "t" + hashlib.sha1(str(data).encode()).hexdigest()[:16])
    return _POSTGRES_DATABASES[data]


def database_contents(data: Path) -> bytes:
    """Everything the station's database holds, as bytes to search: the SQLite files as stored on
    disk, or every row of every table on PostgreSQL."""
    url = station_database(data)
    if url.startswith("sqlite"):
        return b"".join(path.read_bytes() for path in data.glob("evp.sqlite*"))
    import sqlalchemy as sa

    from evp.station.schema import open_engine

    engine = open_engine(url)
    try:
        with engine.connect() as connection:
            tables = sa.MetaData()
            tables.reflect(connection)
            return "".join(repr(row) for table in tables.sorted_tables for row in connection.execute(sa.select(table))).encode()
    finally:
        engine.dispose()


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
def running_station(data: Path, *options: str, port: int | None = None, paired: bool = False, preexec_fn=None) -> Iterator[RunningStation]:
    port = port or free_port()
    log = (data.parent / f"{data.name}-serve.log").open("ab")
    command = [sys.executable, "-m", "evp.cli", "serve", "--host", "127.0.0.1", "--port", str(port), "--data", str(data), *options]
    if os.environ.get("EVP_TEST_POSTGRES") and "--db" not in options:
        command += ["--db", station_database(data)]
    if not paired:
        command.append("--dev-loopback")
    process = subprocess.Popen(command, stdout=log, stderr=subprocess.STDOUT, preexec_fn=preexec_fn)
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


def http_json(station: RunningStation, method: str, path: str, body=None, headers: dict | None = None, credential: str = "") -> tuple[int, dict]:
    """(status, JSON body) of a request to the station; ``credential`` goes as a bearer header."""
    data = None if body is None else (body if isinstance(body, bytes) else json.dumps(body).encode())
    headers = {"Content-Type": "application/json", **(headers or {})}
    if credential:
        headers["Authorization"] = f"Bearer {credential}"
    request = urllib.request.Request(station.http + path, data=data, method=method, headers=headers)
    try:
        with urllib.request.urlopen(request, context=insecure_tls(), timeout=30) as response:
            return response.status, json.loads(response.read() or b"{}")
    except urllib.error.HTTPError as exc:
        text = exc.read()
        try:
            return exc.code, json.loads(text or b"{}")
        except ValueError:
            return exc.code, {"error": text.decode(errors="replace")}


def operator_login_code(station: RunningStation) -> str:
    """A one-time operator code from the station's database, as ``evp pairing-code --role operator`` makes it."""
    from evp.station.auth import Credentials
    from evp.station.store import SessionStore

    store = SessionStore(station_database(station.data))
    try:
        return Credentials(store.engine).issue_code("operator", 60)
    finally:
        store.close()


def operator_credential(station: RunningStation) -> str:
    """Log in as the operator: a one-time code traded for the operator's credential."""
    code = operator_login_code(station)
    status, body = http_json(station, "POST", "/api/pair", {"code": code, "device": "test operator"})
    assert status == 200 and body["role"] == "operator", body
    return body["credential"]


def mobile_credential(station: RunningStation, operator: str, device: str = "test phone") -> str:
    """Pair a phone: the operator asks for a code (the QR code), the phone trades it."""
    status, body = http_json(station, "POST", "/api/pairing", {"role": "mobile"}, credential=operator)
    assert status == 200, body
    status, body = http_json(station, "POST", "/api/pair", {"code": body["code"], "device": device})
    assert status == 200 and body["role"] == "mobile", body
    return body["credential"]


def insecure_tls() -> ssl.SSLContext:
    context = ssl.SSLContext(ssl.PROTOCOL_TLS_CLIENT)
    context.check_hostname = False
    context.verify_mode = ssl.CERT_NONE
    return context


class OperatorFeed:
    """The station's live feed to operator pages (``/ws/operator``), read on a thread, so that a
    test waits for what the station announces (a session ended, interrupted, released) instead of
    sleeping. Everything received since connecting is kept; waits look at all of it."""

    def __init__(self, station: RunningStation, credential: str = ""):
        self.url = f"{station.url}/ws/operator"
        self.headers = {"Authorization": f"Bearer {credential}"} if credential else {}
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
            async with websockets.connect(self.url, ssl=insecure_tls(), additional_headers=self.headers) as connection:
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


@pytest.fixture(scope="session")
def postgres_url() -> Iterator[str]:
    """A real PostgreSQL server for this test session (scripts/postgres.sh: Debian's package,
    installed when missing and possible); the tests that use it skip when it cannot start."""
    pytest.importorskip("psycopg")
    script = Path(__file__).resolve().parents[2] / "scripts" / "postgres.sh"
    folder = Path(tempfile.mkdtemp(prefix="evp-postgres-"))
    folder.chmod(0o755)  # the server runs as 'postgres' when the tests run as root
    data = folder / "data"
    started = subprocess.run(["bash", str(script), "start", str(data), str(free_port())], capture_output=True, text=True, timeout=600)
    if started.returncode != 0:
        shutil.rmtree(folder, ignore_errors=True)
        pytest.skip(f"no PostgreSQL server: {(started.stderr or started.stdout).strip().splitlines()[-1:]}")
    try:
        yield started.stdout.strip().splitlines()[-1]
    finally:
        subprocess.run(["bash", str(script), "stop", str(data)], capture_output=True, timeout=120)
        shutil.rmtree(folder, ignore_errors=True)
