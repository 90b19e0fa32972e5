"""The station's database: sessions, events, telemetry, frames, poses and settings (SQLAlchemy Core).

SQLite under the data folder by default; any SQLAlchemy URL (e.g. PostgreSQL) with ``--db``.
Writes go through one thread that commits whatever is queued each time it wakes, so the event
loop never waits on the disk and a killed client loses nothing that was received. A commit that
fails (a full disk, a database that went away) is kept and retried until it succeeds; meanwhile
:attr:`SessionStore.problem` says why, and ``on_problem`` is told when writing fails and when it
works again, so the station can refuse new recording and tell the operator.
"""

from __future__ import annotations

import itertools
import logging
import os
import queue
import threading
import time
import uuid
from collections.abc import Callable
from pathlib import Path
from typing import Any

from sqlalchemy import (
    Boolean,
    Column,
    Float,
    ForeignKey,
    Integer,
    MetaData,
    String,
    Table,
    Text,
    event,
    insert,
    select,
    update,
)
from sqlalchemy.engine import Engine
from sqlalchemy.exc import DBAPIError, OperationalError

from evp.station.schema import open_engine, upgrade

log = logging.getLogger(__name__)

# A failed commit is retried after RETRY_FIRST_S, doubling up to RETRY_MAX_S: a disk that was
# full is written within 5 s of being freed, and a database that stays down costs one attempt
# every 5 s, not a busy loop.
RETRY_FIRST_S = 0.1
RETRY_MAX_S = 5.0
# Once a row comes, the writer waits this long for more before it commits: a streamed flight's
# telemetry rows then wake it 20 times a second instead of hundreds, each wake-up a fight for the
# interpreter with the event loop (a profile of two streams showed the loop waiting on it).
COLLECT_S = 0.05

metadata = MetaData()

sessions = Table(
    "sessions",
    metadata,
    Column("id", String(32), primary_key=True),
    Column("device", String(128), nullable=False, default=""),
    Column("started_at", Float, nullable=False),
    Column("ended_at", Float),
    Column("status", String(16), nullable=False),  # live | ended | interrupted | failed (its recording could not be opened)
    Column("camera_json", Text),
    Column("mcap_path", Text),
    Column("frames_received", Integer, nullable=False, default=0),
    Column("frames_estimated", Integer, nullable=False, default=0),
    Column("frames_dropped", Integer, nullable=False, default=0),
    Column("owner", String(32), nullable=False, default=""),  # the credential that opened it ("" with dev_loopback)
)
events = Table(
    "events",
    metadata,
    Column("id", Integer, primary_key=True, autoincrement=True),
    Column("session_id", String(32), ForeignKey("sessions.id"), index=True),
    Column("t", Float, nullable=False),
    Column("level", String(8), nullable=False),
    Column("code", String(32), nullable=False),
    Column("text", Text, nullable=False),
)
telemetry = Table(
    "telemetry",
    metadata,
    Column("id", Integer, primary_key=True, autoincrement=True),
    Column("session_id", String(32), ForeignKey("sessions.id"), index=True, nullable=False),
    Column("kind", String(8), nullable=False),
    Column("timestamp", Float, nullable=False),
    Column("received_at", Float, nullable=False),
    Column("data_json", Text, nullable=False),
)
frames = Table(
    "frames",
    metadata,
    Column("id", Integer, primary_key=True, autoincrement=True),
    Column("session_id", String(32), ForeignKey("sessions.id"), index=True, nullable=False),
    Column("seq", Integer, nullable=False),
    Column("timestamp", Float, nullable=False),
    Column("received_at", Float, nullable=False),
    Column("encoding", String(8), nullable=False),
    Column("width", Integer, nullable=False),
    Column("height", Integer, nullable=False),
    Column("size_bytes", Integer, nullable=False),
    Column("estimated", Boolean, nullable=False, default=False),  # False: dropped as stale, or estimation off
)
poses = Table(
    "poses",
    metadata,
    Column("id", Integer, primary_key=True, autoincrement=True),
    Column("session_id", String(32), ForeignKey("sessions.id"), index=True, nullable=False),
    Column("seq", Integer, nullable=False),
    Column("timestamp", Float, nullable=False),
    Column("tx", Float, nullable=False),
    Column("ty", Float, nullable=False),
    Column("tz", Float, nullable=False),
    Column("qw", Float, nullable=False),
    Column("qx", Float, nullable=False),
    Column("qy", Float, nullable=False),
    Column("qz", Float, nullable=False),
    Column("state", String(16), nullable=False),
    Column("quality", Integer, nullable=False),
    Column("reset_counter", Integer, nullable=False),
    Column("processing_ms", Float, nullable=False),
    Column("latency_ms", Float, nullable=False),  # frame received -> pose sent, at the station
)
settings = Table(
    "settings",
    metadata,
    Column("id", Integer, primary_key=True, autoincrement=True),
    Column("session_id", String(32), ForeignKey("sessions.id"), index=True),
    Column("t", Float, nullable=False),
    Column("source", String(16), nullable=False),  # operator | mobile | server
    Column("data_json", Text, nullable=False),
)
credentials = Table(
    "credentials",
    metadata,
    Column("id", String(32), primary_key=True),  # public: sessions.owner, logs
    Column("role", String(16), nullable=False),  # mobile | operator
    Column("name", String(128), nullable=False),
    Column("secret_sha256", String(64), nullable=False),
    Column("created_at", Float, nullable=False),
    Column("revoked_at", Float),
)
pairing_codes = Table(
    "pairing_codes",
    metadata,
    Column("code_sha256", String(64), primary_key=True),
    Column("role", String(16), nullable=False),
    Column("created_at", Float, nullable=False),
    Column("expires_at", Float, nullable=False),
    Column("used_at", Float),
)
TABLES = {table.name: table for table in metadata.sorted_tables}


def make_engine(url: str) -> Engine:
    """An engine with the schema at its current version (:mod:`evp.station.schema`); SQLite gets
    WAL so readers never block the writer, and a new database file is readable by its owner only
    (SQLite gives its journal files the same); a server database's connections are checked before use."""
    engine = open_engine(url)
    if engine.dialect.name == "sqlite":
        database = engine.url.database
        if database and database != ":memory:" and not Path(database).exists():
            os.close(os.open(database, os.O_CREAT | os.O_WRONLY, 0o600))

        @event.listens_for(engine, "connect")
        def _sqlite_pragmas(connection, _record) -> None:
            cursor = connection.cursor()
            cursor.execute("PRAGMA journal_mode=WAL")
            cursor.execute("PRAGMA synchronous=NORMAL")
            cursor.execute("PRAGMA foreign_keys=ON")
            cursor.close()

    upgrade(engine)
    return engine


def _retryable(exc: Exception) -> bool:
    """A failure of the database or its disk, not of the rows: the same commit may work later."""
    return isinstance(exc, OperationalError | OSError) or (isinstance(exc, DBAPIError) and exc.connection_invalidated)


def _first_line(exc: Exception) -> str:
    return f"{exc.__class__.__name__}: {(str(exc).splitlines() or [''])[0][:200]}"


class SessionStore:
    """Queued writes (one committing thread that never gives up on a row) and direct reads."""

    def __init__(self, url: str, on_problem: Callable[[str | None], None] | None = None):
        """``on_problem(text)`` is called (on the writer's thread) when commits start failing, and
        ``on_problem(None)`` when one works again."""
        self.url = url
        self.engine = make_engine(url)
        self.on_problem = on_problem
        self.problem: str | None = None  # why writes are failing now; None while they work
        self.rows_refused = 0  # rows the database refused for good (a bug: logged, never silently)
        self._queue: queue.SimpleQueue = queue.SimpleQueue()
        self._thread = threading.Thread(target=self._write_loop, name="evp-db-writer", daemon=True)
        self._thread.start()

    # --- writes (any thread) -----------------------------------------------------------------

    def insert(self, table: str, **row: Any) -> None:
        self._queue.put(("insert", table, row, None))

    def update_session(self, session_id: str, **values: Any) -> None:
        self._queue.put(("update", "sessions", values, session_id))

    def create_session(self, device: str, mcap_path: str, owner: str = "") -> str:
        session_id = time.strftime("%Y%m%d-%H%M%S-") + uuid.uuid4().hex[:6]
        self.insert("sessions", id=session_id, device=device, started_at=time.time(), status="live", mcap_path=mcap_path, owner=owner)
        return session_id

    def log_event(self, session_id: str | None, level: str, code: str, text: str) -> dict:
        row = {"session_id": session_id, "t": time.time(), "level": level, "code": code, "text": text}
        self.insert("events", **row)
        return row

    def flush(self, timeout: float = 5.0) -> bool:
        """Wait until every write queued before this call is committed, for a read that decides
        something (a resume must see the session's end); False when the database did not take
        them within ``timeout`` (its problem is reported apart)."""
        committed = threading.Event()
        self._queue.put(committed)
        return committed.wait(timeout)

    def close(self) -> None:
        self._queue.put(None)
        self._thread.join(timeout=30)
        self.engine.dispose()

    def _write_loop(self) -> None:
        """Commit what is queued; a batch that fails stays first in line (newer writes join it)
        and is retried, so rows are written in order and none is dropped while the database or
        its disk fails."""
        batch: list = []
        flushes: list[threading.Event] = []  # set once what was queued before them is committed
        delay = RETRY_FIRST_S
        stop = False
        while True:
            if not batch:
                batch.append(self._queue.get())
                if isinstance(batch[0], tuple):
                    time.sleep(COLLECT_S)
            while not self._queue.empty():
                batch.append(self._queue.get())
            stop = stop or None in batch
            flushes += [b for b in batch if isinstance(b, threading.Event)]
            batch = [b for b in batch if isinstance(b, tuple)]
            try:
                self._commit_or_isolate(batch)
            except Exception as exc:  # noqa: BLE001 - whatever the database says, the writer goes on
                self._set_problem(f"database writes failing ({len(batch)} rows waiting): {_first_line(exc)}")
                try:  # wait, collecting newer writes; a close does not cut the retries short
                    batch.append(self._queue.get(timeout=delay))
                except queue.Empty:
                    pass
                delay = min(2 * delay, RETRY_MAX_S)
                continue
            delay = RETRY_FIRST_S
            self._set_problem(None)
            for committed in flushes:
                committed.set()
            flushes.clear()
            if stop:
                return

    def _set_problem(self, text: str | None) -> None:
        changed = (text is None) != (self.problem is None)
        self.problem = text
        if changed:
            log.warning("%s", text or "database writes work again")
            if self.on_problem is not None:
                self.on_problem(text)

    def _commit_or_isolate(self, batch: list[tuple]) -> None:
        """One transaction for the batch (emptied once written); if the database refuses the rows
        themselves, not for its disk or link, each row alone, so one bad row holds back no other."""
        try:
            self._commit(batch)
        except Exception as exc:  # noqa: BLE001
            if _retryable(exc):
                raise
            while batch:
                try:
                    self._commit(batch[:1])
                except Exception as row_exc:  # noqa: BLE001
                    if _retryable(row_exc):
                        raise
                    self._refused(batch[0], row_exc)
                del batch[0]
        batch.clear()

    def _refused(self, row: tuple, exc: Exception) -> None:
        self.rows_refused += 1
        log.error("database refused a %s of %s: %s", row[0], row[1], _first_line(exc))

    def _commit(self, batch: list[tuple]) -> None:
        """One transaction; a run of inserts into one table goes as one executemany, in the order
        they came: one statement a row cost the writer, and through the GIL the event loop, 5 times
        more (110 against 23 us a telemetry row, SQLite)."""
        with self.engine.begin() as connection:
            for (kind, table, _), run in itertools.groupby(batch, key=lambda row: (row[0], row[1], row[2].keys())):
                if kind == "insert":
                    connection.execute(insert(TABLES[table]), [values for _, _, values, _ in run])
                else:
                    for _, _, values, session_id in run:
                        connection.execute(update(sessions).where(sessions.c.id == session_id).values(**values))

    # --- reads (call from a worker thread in async code) -------------------------------------

    def session(self, session_id: str) -> dict | None:
        with self.engine.connect() as connection:
            row = connection.execute(select(sessions).where(sessions.c.id == session_id)).mappings().first()
        return dict(row) if row else None

    def list_sessions(self, limit: int | None = 200, status: str | None = None) -> list[dict]:
        query = select(sessions).order_by(sessions.c.started_at.desc()).limit(limit)
        if status is not None:
            query = query.where(sessions.c.status == status)
        with self.engine.connect() as connection:
            rows = connection.execute(query).mappings().all()
        return [dict(r) for r in rows]

    def rows(self, table: str, session_id: str) -> list[dict]:
        """Every row of one session in a table, in insertion order."""
        target = TABLES[table]
        with self.engine.connect() as connection:
            rows = connection.execute(select(target).where(target.c.session_id == session_id).order_by(target.c.id)).mappings().all()
        return [dict(r) for r in rows]

    def recent_events(self, limit: int = 200) -> list[dict]:
        with self.engine.connect() as connection:
            rows = connection.execute(select(events).order_by(events.c.id.desc()).limit(limit)).mappings().all()
        return [dict(r) for r in reversed(rows)]

    def mark_live_sessions_interrupted(self) -> list[str]:
        """Sessions left 'live' by a station that stopped without closing them."""
        with self.engine.begin() as connection:
            ids = list(connection.execute(select(sessions.c.id).where(sessions.c.status == "live")).scalars())
            if ids:
                connection.execute(update(sessions).where(sessions.c.id.in_(ids)).values(status="interrupted", ended_at=time.time()))
        return ids
