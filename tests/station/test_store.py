"""Issue 34, finding 8: the station's database on SQLite and on a real PostgreSQL server.

Every test here runs against both (PostgreSQL from scripts/postgres.sh, skipped when it cannot be
started): schema versions and migrations, an old unversioned database upgraded in place, the
store's reads and writes, pairing codes used exactly once under a race, the health check; and a
``postgresql://`` URL without its driver or server is one clear line, not a traceback.
"""

from __future__ import annotations

import subprocess
import sys
import threading
import time

import pytest
import sqlalchemy as sa

from evp.errors import ConfigError
from evp.station.auth import Credentials, PairingError
from evp.station.schema import head, health, open_engine, upgrade, version
from evp.station.store import SessionStore
from tests.conftest import SAMPLE
from tests.station.conftest import OperatorFeed, new_postgres_database, run_stream, running_station


@pytest.fixture(params=["sqlite", "postgresql"])
def database(request, tmp_path) -> str:
    """A fresh, empty database of each kind (PostgreSQL: a new database on the test server)."""
    if request.param == "sqlite":
        return f"sqlite:///{tmp_path / 'evp.sqlite'}"
    return new_postgres_database(request.getfixturevalue("postgres_url"))


def _wait_for(check, what: str) -> None:
    deadline = time.monotonic() + 10
    while not check():
        assert time.monotonic() < deadline, what
        time.sleep(0.02)


def test_a_new_database_gets_the_newest_schema_and_the_store_reads_what_it_wrote(database):
    store = SessionStore(database)
    try:
        assert version(store.engine) == head() == "0002"
        session_id = store.create_session("phone", "/tmp/x.mcap", owner="abc123")
        store.insert("frames", session_id=session_id, seq=0, timestamp=1.5, received_at=2.0, encoding="png", width=4, height=3, size_bytes=10, estimated=True)
        store.log_event(session_id, "info", "connected", "hello")
        _wait_for(lambda: len(store.rows("frames", session_id)) == 1 and len(store.rows("events", session_id)) == 1, "the writes committed")
        assert store.session(session_id)["owner"] == "abc123"
        assert store.mark_live_sessions_interrupted() == [session_id]
        assert [s["status"] for s in store.list_sessions()] == ["interrupted"]
        assert health(store.engine) is None
    finally:
        store.close()


def test_a_flush_returns_once_every_earlier_write_is_committed(database):
    """A resume reads the session's row to refuse an ended session: the end, queued a moment
    before, must be in it (the writer collects rows for COLLECT_S before committing)."""
    store = SessionStore(database)
    try:
        session_id = store.create_session("phone", "/tmp/x.mcap")
        for seq in range(50):
            store.insert(
                "frames", session_id=session_id, seq=seq, timestamp=seq, received_at=seq, encoding="png", width=4, height=3, size_bytes=10, estimated=True
            )
        store.update_session(session_id, status="ended")
        assert store.flush()
        assert store.session(session_id)["status"] == "ended" and len(store.rows("frames", session_id)) == 50
    finally:
        store.close()


def test_a_database_from_before_schema_versions_is_upgraded_in_place(database):
    engine = open_engine(database)
    from alembic import command

    from evp.station.schema import _alembic_config

    with engine.begin() as connection:  # the first release's tables, no version table: what create_all left
        command.upgrade(_alembic_config(connection), "0001")
        connection.execute(sa.text("DROP TABLE alembic_version"))
        connection.execute(
            sa.text(
                "INSERT INTO sessions (id, device, started_at, status, frames_received, frames_estimated, frames_dropped) VALUES ('old', 'p', 1, 'ended', 0, 0, 0)"
            )
        )
    assert upgrade(engine) == "0002"
    with engine.connect() as connection:
        assert connection.execute(sa.text("SELECT owner FROM sessions WHERE id = 'old'")).scalar_one() == ""  # nobody's: no phone resumes it
    assert upgrade(engine) == "0002"  # idempotent
    engine.dispose()


def test_a_pairing_code_gives_one_credential_even_to_racing_devices(database):
    store = SessionStore(database)
    try:
        credentials = Credentials(store.engine)
        code = credentials.issue_code("mobile", 60)
        results: list = []

        def attempt(name: str) -> None:
            try:
                results.append(credentials.pair(code, name))
            except PairingError as exc:
                results.append(exc)

        threads = [threading.Thread(target=attempt, args=(f"phone {k}",)) for k in range(4)]
        for thread in threads:
            thread.start()
        for thread in threads:
            thread.join()
        paired = [r for r in results if not isinstance(r, PairingError)]
        assert len(paired) == 1
        identity, secret = paired[0]
        assert credentials.identify(secret) == identity and identity.role == "mobile"
        assert credentials.identify(secret[:-1] + ("A" if secret[-1] != "A" else "B")) is None
        expired = Credentials(store.engine, clock=lambda: time.time() - 120).issue_code("operator", 60)
        with pytest.raises(PairingError):
            credentials.pair(expired, "late")
        assert credentials.revoke(identity.credential_id) and credentials.identify(secret) is None
    finally:
        store.close()


def test_unusable_database_urls_are_one_clear_line(monkeypatch, postgres_url):
    monkeypatch.setitem(sys.modules, "psycopg", None)  # the 'postgres' extra not installed
    with pytest.raises(ConfigError, match=r"driver is not installed \(pip install 'evp\[postgres\]'\)"):
        open_engine("postgresql://evp@127.0.0.1/evp")
    monkeypatch.delitem(sys.modules, "psycopg")
    with pytest.raises(ConfigError, match="not a database URL"):
        open_engine("postgres ql://nonsense")
    unreachable = postgres_url.rpartition(":")[0] + ":1/evp"
    result = subprocess.run([sys.executable, "-m", "evp.cli", "pairing-code", "--db", unreachable], capture_output=True, text=True, timeout=120)
    assert result.returncode != 0 and "Traceback" not in result.stderr
    assert result.stderr.strip().startswith("error: cannot open the station database") and len(result.stderr.strip().splitlines()) == 1


def test_the_station_records_a_stream_in_postgresql(postgres_url, station_data, tmp_path):
    url = new_postgres_database(postgres_url)
    with running_station(station_data, "--db", url) as station, OperatorFeed(station) as feed:
        summary = run_stream(
            str(SAMPLE),
            "--url",
            station.url,
            "--cafile",
            str(station_data / "tls" / "cert.pem"),
            "--quiet",
            "--max-frames",
            "5",
            "--credential-file",
            str(tmp_path / "none"),
        )
        feed.event("ended", summary["session_id"])
    store = SessionStore(url)
    try:
        _wait_for(lambda: store.session(summary["session_id"])["frames_received"] == 5, "the session's counts")
        assert len(store.rows("poses", summary["session_id"])) == summary["poses_received"] == 5
    finally:
        store.close()
