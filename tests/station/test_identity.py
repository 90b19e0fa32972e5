"""Issue 34, finding 2: nobody takes over a session or the operator's controls.

Two paired phones (A streams, B is the attacker), the operator, and a client with no credential
try every takeover step the issue lists; none succeeds, and the owner keeps its session. Then the
cross-site requests a browser holding the operator's login could be made to send, and where the
secrets end up (hashed in the database, in no log).
"""

from __future__ import annotations

import asyncio
import contextlib
import json

import pytest
import websockets

from evp.io.registry import open_dataset
from evp.station.protocol import PROTOCOL_VERSION, Hello, encode
from evp.station.store import SessionStore
from tests.conftest import SAMPLE
from tests.station.conftest import (
    OperatorFeed,
    committed,
    database_contents,
    http_json,
    insecure_tls,
    mobile_credential,
    operator_credential,
    running_station,
    station_database,
)
from tests.station.test_faults import _connect, _open_session, _stream_until_posed


@pytest.fixture(scope="module")
def frames():
    dataset = open_dataset(SAMPLE)
    return dataset.camera, list(dataset.frames())[:6]


async def _hello_answer(url: str, credential: str, resume: str | None = None) -> str:
    """What the station answers a hello with: 'welcome' or the error code; then a bye attempt
    (which must not end anybody's session) and the link closes."""
    connection = await _connect(url)
    try:
        await connection.send(encode(Hello(protocol=PROTOCOL_VERSION, token=credential, device="attacker", resume=resume)))
        reply = json.loads(await asyncio.wait_for(connection.recv(), 20))
        with contextlib.suppress(websockets.ConnectionClosed):
            await connection.send('{"type": "bye"}')
        return "welcome" if reply["type"] == "welcome" else reply["code"]
    finally:
        await connection.close()


async def _operator_feed_opens(url: str, headers: dict) -> bool:
    try:
        async with websockets.connect(f"{url}/ws/operator", ssl=insecure_tls(), additional_headers=headers) as connection:
            await asyncio.wait_for(connection.recv(), 10)
            return True
    except websockets.InvalidStatus:
        return False


def test_takeover_steps_all_fail_with_and_without_the_operators_credential(station_data, frames):
    camera, images = frames
    with running_station(station_data, paired=True) as station:
        operator = operator_credential(station)
        phone_a, phone_b = mobile_credential(station, operator, "A"), mobile_credential(station, operator, "B")
        strangers = {"no credential": "", "phone B": phone_b, "operator": operator}

        async def scenario() -> tuple[str, str]:
            live, welcome = await _open_session(station.url, camera, credential=phone_a)
            await _stream_until_posed(live, images[:2], 0)
            for who, credential in strangers.items():  # lock the phone out while it streams
                assert await _hello_answer(station.url, credential, resume=welcome.session_id) in ("unknown_session", "bad_token"), who
            await _stream_until_posed(live, images[2:3], 2)  # A's link was not touched
            live.transport.abort()  # A's link dies: the session is interrupted, awaiting A
            return welcome.session_id

        with OperatorFeed(station, operator) as feed:
            session_id = asyncio.run(scenario())
            feed.event("interrupted", session_id, timeout=20)
            for who, credential in strangers.items():  # resume, inject, end an interrupted session
                assert asyncio.run(_hello_answer(station.url, credential, resume=session_id)) in ("unknown_session", "bad_token"), who
            # the owner comes back and ends it
            resumed = asyncio.run(_resume_and_end(station.url, camera, images, session_id, phone_a))
            assert resumed == 3
            feed.event("ended", session_id)
            for who, credential in strangers.items():  # an ended session
                assert asyncio.run(_hello_answer(station.url, credential, resume=session_id)) in ("unknown_session", "bad_token"), who

        # the operator API with a phone's credential or none
        for who, credential in {"no credential": "", "phone B": phone_b}.items():
            assert http_json(station, "GET", "/api/sessions", credential=credential)[0] in (401, 403), who
            assert http_json(station, "GET", "/api/state", credential=credential)[0] in (401, 403), who
            assert http_json(station, "POST", "/api/configure", {"fps": 5}, credential=credential)[0] in (401, 403), who
            assert http_json(station, "POST", f"/api/sessions/{session_id}/stop", {}, credential=credential)[0] in (401, 403), who
            assert http_json(station, "POST", "/api/pairing", {"role": "operator"}, credential=credential)[0] in (401, 403), who
            assert http_json(station, "GET", f"/api/sessions/{session_id}/trajectory.tum", credential=credential)[0] in (401, 403), who
            headers = {"Authorization": f"Bearer {credential}"} if credential else {}
            assert not asyncio.run(_operator_feed_opens(station.url, headers)), who
        assert http_json(station, "GET", "/api/sessions", credential=operator)[0] == 200  # the operator's own role

        store = SessionStore(station_database(station_data))
        try:
            committed(lambda: store.session(session_id)["status"] == "ended", "the ended status")
            assert len(store.rows("frames", session_id)) == 4  # nothing injected
            assert [e["code"] for e in store.rows("events", session_id)].count("resumed") == 1  # by its owner, once
        finally:
            store.close()


async def _resume_and_end(url: str, camera, images, session_id: str, credential: str) -> int:
    connection, welcome = await _open_session(url, camera, resume=session_id, credential=credential)
    assert welcome.resumed
    await _stream_until_posed(connection, images[3:4], welcome.next_seq)
    await connection.send('{"type": "bye"}')
    await connection.close()
    return welcome.next_seq


def test_cross_site_requests_are_refused_even_with_the_operators_login(station_data):
    with running_station(station_data, paired=True) as station:
        operator = operator_credential(station)
        cookie = {"Cookie": f"evp_operator={operator}"}
        evil = {"Origin": "https://evil.example"}
        own = {"Origin": station.http}
        # a cross-site form or text/plain POST carries the cookie but no JSON content type, and a foreign Origin
        assert http_json(station, "POST", "/api/configure", b'{"fps": 5}', {**cookie, **evil, "Content-Type": "text/plain"})[0] == 403
        assert http_json(station, "POST", "/api/configure", b'{"fps": 5}', {**cookie, "Content-Type": "text/plain"})[0] == 415
        assert http_json(station, "POST", "/api/configure", {"fps": 5}, {**cookie, **evil})[0] == 403
        assert http_json(station, "POST", "/api/configure", {"fps": 5}, {**cookie, **own})[0] == 200  # the operator page itself
        assert not asyncio.run(_operator_feed_opens(station.url, {**cookie, **evil}))
        assert asyncio.run(_operator_feed_opens(station.url, {**cookie, **own}))

        async def mobile_from(origin: str) -> bool:
            try:
                async with websockets.connect(f"{station.url}/ws/mobile", ssl=insecure_tls(), origin=origin):
                    return True
            except websockets.InvalidStatus:
                return False

        assert not asyncio.run(mobile_from("https://evil.example"))
        assert asyncio.run(mobile_from(station.http))


def test_pairing_codes_are_one_use_credentials_hashed_revocable_and_never_logged(station_data, frames):
    camera, images = frames
    with running_station(station_data, paired=True) as station:
        operator = operator_credential(station)
        status, offer = http_json(station, "POST", "/api/pairing", {"role": "mobile"}, credential=operator)
        assert status == 200 and "#pair=" in offer["url"] and "<svg" in offer["qr_svg"]
        status, first = http_json(station, "POST", "/api/pair", {"code": offer["code"], "device": "phone"})
        assert status == 200
        assert http_json(station, "POST", "/api/pair", {"code": offer["code"], "device": "copy"})[0] == 403  # one use
        phone = first["credential"]
        assert asyncio.run(_hello_answer(station.url, phone)) == "welcome"
        devices = http_json(station, "GET", "/api/devices", credential=operator)[1]["devices"]
        assert {d["role"] for d in devices} == {"mobile", "operator"} and all("secret_sha256" not in d for d in devices)
        assert http_json(station, "POST", f"/api/devices/{first['credential_id']}/revoke", {}, credential=operator)[0] == 200
        assert asyncio.run(_hello_answer(station.url, phone)) == "bad_token"
        assert http_json(station, "GET", "/api/health", credential=operator)[1] == {"database": "ok", "schema_version": "0002"}
        guesses = [http_json(station, "POST", "/api/pair", {"code": f"guess-{k}", "device": "x"})[0] for k in range(7)]
        assert guesses == [403] * 4 + [429] * 3, "the copy above was this client's first failure"
    store = SessionStore(station_database(station_data))
    try:
        refusals = [event["text"] for event in store.recent_events() if event["code"] == "pairing_refused"]
    finally:
        store.close()
    assert len(refusals) == 5 and "refused unchecked for 60 s" in refusals[-1], "the event log hears of the limit once, then nothing"
    secrets = [phone.partition(".")[2], operator.partition(".")[2], offer["code"]]
    stored = database_contents(station_data)
    log = (station_data.parent / f"{station_data.name}-serve.log").read_bytes()
    for secret in secrets:
        assert secret.encode() not in stored and secret.encode() not in log
