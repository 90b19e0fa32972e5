"""The station's database: sessions, events, telemetry, frames, poses and settings (SQLAlchemy Core).

SQLite under the data folder by default; any SQLAlchemy URL (e.g. PostgreSQL) with ``--db``.
Writes go through one thread that commits whatever is queued each time it wakes, so the event
loop never waits on the disk and a killed client loses nothing that was received.
"""

from __future__ import annotations

import queue
import threading
import time
import uuid
from collections.abc import Iterable
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

from evp.station.schema import open_engine, upgrade

metadata = MetaData()

sessions = Table(
    "sessions",
    metadata,
    Column("id", String(32), primary_key=True),
    Column("device", String(128), nullable=False, default=""),
    Column("started_at", Float, nullable=False),
    Column("ended_at", Float),
    Column("status", String(16), nullable=False),  # live | ended | interrupted
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
    WAL so readers never block the writer; a server database's connections are checked before use."""
    engine = open_engine(url)
    if engine.dialect.name == "sqlite":

        @event.listens_for(engine, "connect")
        def _sqlite_pragmas(connection, _record) -> None:
            cursor = connection.cursor()
            cursor.execute("PRAGMA journal_mode=WAL")
            cursor.execute("PRAGMA synchronous=NORMAL")
            cursor.execute("PRAGMA foreign_keys=ON")
            cursor.close()

    upgrade(engine)
    return engine


class SessionStore:
    """Queued writes (one committing thread) and direct reads."""

    def __init__(self, url: str):
        self.url = url
        self.engine = make_engine(url)
        self._queue: queue.Queue = queue.Queue()
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

    def close(self) -> None:
        self._queue.put(None)
        self._thread.join(timeout=30)
        self.engine.dispose()

    def _write_loop(self) -> None:
        while True:
            item = self._queue.get()
            batch = [item]
            while not self._queue.empty():
                batch.append(self._queue.get())
            stop = None in batch
            self._commit(b for b in batch if b is not None)
            if stop:
                return

    def _commit(self, batch: Iterable[tuple]) -> None:
        with self.engine.begin() as connection:
            for kind, table, values, session_id in batch:
                if kind == "insert":
                    connection.execute(insert(TABLES[table]), [values])
                else:
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
