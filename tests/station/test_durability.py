"""Durable recording and a supervised estimator, driven in-process (no sockets): a failed commit is
retried until it is written; below the disk watermark nothing new is recorded and every refusal
is explicit; a dead estimator's frame in flight gets an error, the estimator is restarted, and
every frame is answered exactly once (issue 34, findings 1 and 5)."""

from __future__ import annotations

import asyncio
import json
import os
import signal
import sqlite3
import threading
import time

import pytest
from sqlalchemy.exc import OperationalError

from evp.config import Settings
from evp.io.registry import open_dataset
from evp.station.base_station import Station
from evp.station.protocol import PROTOCOL_VERSION, Config, Hello, ProtocolError, decode_text, encode, encode_image
from evp.station.store import SessionStore
from tests.conftest import SAMPLE
from tests.station.conftest import committed, indexed_messages


@pytest.fixture(scope="module")
def frames():
    dataset = open_dataset(SAMPLE)
    return dataset.camera, [encode_image(f.image, k, f.timestamp, "png") for k, f in enumerate(list(dataset.frames())[:8])]


def _disk_full() -> OperationalError:
    return OperationalError("INSERT INTO frames", {}, sqlite3.OperationalError("database or disk is full"))


def test_a_failed_commit_is_retried_and_nothing_is_lost(tmp_path):
    """Finding 1: one failed commit (a full disk) killed the writer thread for good."""
    told: list[str | None] = []
    store = SessionStore(f"sqlite:///{tmp_path / 'evp.sqlite'}", on_problem=told.append)
    commit, full = store._commit, threading.Event()
    full.set()

    def commit_unless_full(batch):
        if full.is_set():
            raise _disk_full()
        commit(batch)

    store._commit = commit_unless_full
    try:
        session_id = store.create_session("phone", "")
        for seq in range(40):
            store.insert("frames", session_id=session_id, seq=seq, timestamp=seq, received_at=seq, encoding="png", width=1, height=1, size_bytes=1)
        committed(lambda: bool(told), "the failure to its listener", timeout=10)
        assert "disk is full" in told[0] and "database writes failing" in store.problem
        time.sleep(0.3)  # retried meanwhile, nothing lost
        full.clear()  # space freed
        committed(lambda: len(store.rows("frames", session_id)) == 40, "the 40 queued frames after the disk was freed", timeout=15)
        assert told[-1] is None and store.problem is None and store._thread.is_alive()
        store.insert("events", session_id=session_id, t=1.0, level="info", code="later", text="written too")
        committed(lambda: [e["code"] for e in store.rows("events", session_id)] == ["later"], "a write after the recovery")
        assert store.rows_refused == 0
    finally:
        store.close()


def test_a_row_the_database_refuses_for_good_does_not_hold_back_the_others(tmp_path):
    store = SessionStore(f"sqlite:///{tmp_path / 'evp.sqlite'}")
    try:
        session_id = store.create_session("phone", "")
        store.insert("frames", session_id=session_id, seq=0)  # NOT NULL columns missing: refused for good
        store.log_event(session_id, "info", "after", "a good row behind a bad one")
        committed(lambda: [e["code"] for e in store.rows("events", session_id)] == ["after"], "the good row")
        assert store.rows_refused == 1 and store.problem is None
    finally:
        store.close()


class Phone:
    """A session's replies, decoded; ``answers[seq]`` lists what each frame got."""

    def __init__(self, session):
        self.messages: list = []
        session.attach(lambda text: self.messages.append(decode_text(text)))

    def answers(self) -> dict[int, list[str]]:
        found: dict[int, list[str]] = {}
        for m in self.messages:
            if m.type in ("pose", "dropped") or (m.type == "error" and m.seq is not None):
                found.setdefault(m.seq, []).append(m.type if m.type != "error" else m.code)
        return found

    async def until(self, predicate, timeout: float = 60.0, what: str = "") -> None:
        deadline = time.monotonic() + timeout
        while not any(predicate(m) for m in self.messages):
            assert time.monotonic() < deadline, f"no {what} within {timeout:g} s: {self.messages[-5:]}"
            await asyncio.sleep(0.02)


def _station(tmp_path, **station_settings) -> Station:
    settings = Settings.model_validate({"station": station_settings})
    return Station(tmp_path / "data", settings)


def _events(station: Station, queue: asyncio.Queue) -> list[str]:
    codes = []
    while not queue.empty():
        message = json.loads(queue.get_nowait())
        if message["type"] == "event":
            codes.append(message["event"]["code"])
    return codes


def test_below_the_disk_watermark_nothing_new_is_recorded_and_each_refusal_is_explicit(tmp_path, frames):
    """Finding 1: new recording is refused explicitly while the station cannot write."""
    camera, images = frames
    free = {"bytes": 10**12}
    station = _station(tmp_path, min_free_disk_mb=500)
    station.storage.measure = lambda _path: free["bytes"]
    operators: asyncio.Queue = asyncio.Queue()
    station.operators.add(operators)
    try:
        session, _ = station.open_session(Hello(protocol=PROTOCOL_VERSION, device="phone"))
        phone = Phone(session)
        session.on_binary(images[0].pack(), 1.0)  # no camera yet: recorded, dropped not_configured
        free["bytes"] = 100 * 10**6
        station.storage._checked_at = -1e9  # measure now
        session.on_binary(images[1].pack(), 2.0)
        session.on_text('{"type": "telemetry", "kind": "baro", "timestamp": 5, "pressure_pa": 101325}', 2.1)
        station.check_storage()
        with pytest.raises(ProtocolError, match="below the 500 MB watermark") as refused:
            station.open_session(Hello(protocol=PROTOCOL_VERSION, device="another"))
        assert refused.value.code == "storage_full"
        assert phone.answers() == {0: ["dropped"], 1: ["storage_full"]}
        errors = [m for m in phone.messages if m.type == "error"]
        assert [e.code for e in errors] == ["storage_full", "storage_full"] and "watermark" in errors[0].message
        assert any(m.type == "status" and "watermark" in m.message for m in phone.messages)
        free["bytes"] = 10**12
        station.storage._checked_at = -1e9
        station.check_storage()
        session.on_binary(images[1].pack(), 3.0)  # the same frame again, now taken
        assert phone.answers()[1] == ["storage_full", "dropped"]
        assert _events(station, operators).count("storage_full") == 1  # told once, not per frame
        session.recording.close()
    finally:
        station.store.close()
    store = SessionStore(station.store.url)
    try:
        assert [r["seq"] for r in store.rows("frames", session.id)] == [0, 1]
        assert store.rows("telemetry", session.id) == []
        assert {"storage_full", "storage_ok"} <= {e["code"] for e in store.recent_events(50)}
    finally:
        store.close()
    images_recorded = [t for t, _, _ in indexed_messages(session.recording.path) if t.startswith("/camera/image")]
    assert len(images_recorded) == 2


def test_a_dead_estimator_answers_its_frame_in_flight_and_is_restarted(tmp_path, frames):
    """Finding 5: the estimator process died; the frame in flight was never answered, later
    frames were dropped as estimation_off while the status said starting, and re-sending the
    config did not restart it."""
    camera, images = frames

    async def scenario() -> tuple[Phone, list[str]]:
        station = _station(tmp_path, max_estimator_restarts=1)
        operators: asyncio.Queue = asyncio.Queue()
        station.operators.add(operators)
        session, _ = station.open_session(Hello(protocol=PROTOCOL_VERSION, device="phone"))
        phone = Phone(session)
        config = encode(Config(camera=camera))

        async def running() -> None:
            phone.messages = [m for m in phone.messages if m.type != "status"]  # wait for a new one
            await phone.until(
                lambda m: m.type == "status" and m.state == "running" and session.worker is not None and session.worker.ready, what="a ready estimator"
            )

        async def posed(seq: int) -> None:
            session.on_binary(images[seq].pack(), time.time())
            await phone.until(lambda m: m.type in ("pose", "error", "dropped") and getattr(m, "seq", None) == seq, what=f"frame {seq}'s answer")

        def kill() -> None:
            os.kill(session.worker._process.pid, signal.SIGKILL)
            session.worker._process.join()

        try:
            session.on_text(config, time.time())
            await running()
            await posed(0)
            kill()
            session.on_binary(images[1].pack(), time.time())  # in flight when its process is found dead
            await phone.until(lambda m: m.type == "error" and m.seq == 1, what="frame 1's error")
            await phone.until(lambda m: m.type == "status" and m.state == "running" and session.worker.ready, what="the restarted estimator")
            kill()  # dies again without a pose in between: past max_estimator_restarts, left down
            await phone.until(lambda m: m.type == "status" and m.state == "failed", what="the failed status")
            await posed(2)
            session.on_text(config, time.time())  # the same config restarts it
            await running()
            await posed(3)
            return phone, _events(station, operators)
        finally:
            await session.close("ended")
            station.store.close()

    phone, events = asyncio.run(scenario())
    answers = phone.answers()
    assert answers == {0: ["pose"], 1: ["estimator_failed"], 2: ["estimator_failed"], 3: ["pose"]}  # each exactly once
    assert events.count("estimator_restarted") == 1 and "estimator_failed" in events  # the operator is told


def test_session_ids_are_checked_ended_sessions_are_final_and_an_unopenable_recording_is_not_live(tmp_path):
    """Finding 7: a '"' in a session id chose a download's file name; ended sessions could be
    resumed; a session whose file could not be opened stayed "live"."""
    from evp.station.server import _no_such_session

    station = _station(tmp_path)
    try:
        for hostile in ('x"; filename="evil.sh', "../../etc/passwd", "20261127-114952-c4546Z"):
            with pytest.raises(ProtocolError, match="not a session id") as refused:
                station.open_session(Hello(protocol=PROTOCOL_VERSION, resume=hostile))
            assert refused.value.code == "unknown_session"
            assert _no_such_session(hostile).status_code == 404
        assert _no_such_session("20261127-114952-c45464") is None
        session, _ = station.open_session(Hello(protocol=PROTOCOL_VERSION, device="phone"))
        session.ended = True  # bye
        with pytest.raises(ProtocolError, match="ended sessions are final") as refused:
            station.open_session(Hello(protocol=PROTOCOL_VERSION, resume=session.id))
        assert refused.value.code == "session_ended"
        station.sessions.clear()
        station.store.update_session(session.id, status="ended")
        committed(lambda: (station.store.session(session.id) or {}).get("status") == "ended", "the ended status")
        with pytest.raises(ProtocolError, match="ended sessions are final"):  # reopened from the database
            station.open_session(Hello(protocol=PROTOCOL_VERSION, resume=session.id))
        session.recording.close()
        sessions = station.data_dir / "sessions"
        for path in sessions.iterdir():
            path.unlink()
        sessions.rmdir()
        sessions.write_text("a file where the recordings' folder should be")
        with pytest.raises(ProtocolError, match="recording cannot be opened") as refused:
            station.open_session(Hello(protocol=PROTOCOL_VERSION, device="phone"))
        assert refused.value.code == "storage_full"
        committed(lambda: [r["status"] for r in station.store.list_sessions()].count("failed") == 1, "the failed session")
        assert [r["status"] for r in station.store.list_sessions()].count("live") == 0
    finally:
        station.store.close()
