"""Bad input and faults: each gets a specific error, is logged, and the session goes on; a client
killed mid-stream leaves an interrupted, durable session that a reconnect resumes; a killed
station loses nothing it recorded."""

from __future__ import annotations

import asyncio
import json
import signal
import time
import urllib.error
import urllib.request

import numpy as np
import pytest
import websockets

from evp.io.registry import open_dataset
from evp.station.protocol import PROTOCOL_VERSION, Config, Hello, ImageMessage, decode_text, encode, encode_image
from evp.station.recording import has_summary
from evp.station.store import SessionStore
from evp.types import CameraModel
from tests.conftest import SAMPLE
from tests.station.conftest import (
    OperatorFeed,
    committed,
    indexed_messages,
    insecure_tls,
    mobile_credential,
    operator_credential,
    running_station,
    station_database,
)


@pytest.fixture(scope="module")
def frames():
    dataset = open_dataset(SAMPLE)
    return dataset.camera, list(dataset.frames())[:12]


async def _connect(url: str):
    return await websockets.connect(f"{url}/ws/mobile", ssl=insecure_tls(), max_size=2**25)


async def _until(connection, wanted: str, timeout: float = 60.0):
    """Messages until one of type ``wanted``; returns (that message, everything before it)."""
    seen = []
    deadline = time.monotonic() + timeout
    while True:
        message = decode_text(await asyncio.wait_for(connection.recv(), max(0.1, deadline - time.monotonic())))
        if message.type == wanted:
            return message, seen
        seen.append(message)


async def _open_session(url: str, camera: CameraModel, resume: str | None = None, credential: str = ""):
    connection = await _connect(url)
    await connection.send(encode(Hello(protocol=PROTOCOL_VERSION, token=credential, device="test", resume=resume)))
    welcome, _ = await _until(connection, "welcome")
    await connection.send(encode(Config(camera=camera)))
    while (await _until(connection, "status"))[0].state != "running":
        pass
    return connection, welcome


async def _stream_until_posed(connection, images, first_seq: int) -> None:
    """Send frames one at a time, each after the previous one's pose came back."""
    for seq, frame in enumerate(images, start=first_seq):
        await connection.send(encode_image(frame.image, seq, frame.timestamp, "png").pack())
        await _until(connection, "pose")


async def _refused(url: str, first) -> tuple[str, str]:
    connection = await _connect(url)
    await connection.send(first)
    error, _ = await _until(connection, "error", 20)
    await connection.close()
    return error.code, error.message


def _http_status(url: str) -> int:
    try:
        with urllib.request.urlopen(url, context=insecure_tls(), timeout=10) as response:
            return response.status
    except urllib.error.HTTPError as exc:
        return exc.code


def _store(data) -> SessionStore:
    return SessionStore(station_database(data))


def test_bad_messages_get_specific_errors_and_the_session_goes_on(station_data, frames):
    camera, images = frames

    async def scenario(url: str, phone: str) -> tuple[str, list[str]]:
        hello = lambda **kw: encode(Hello(**{"protocol": PROTOCOL_VERSION, "token": phone, **kw}))  # noqa: E731
        assert (await _refused(url, hello(token="wrong")))[0] == "bad_token"
        assert (await _refused(url, hello(token="")))[0] == "bad_token"
        assert (await _refused(url, hello(protocol=99)))[0] == "bad_version"
        assert (await _refused(url, b"\x00\x01"))[0] == "not_ready"
        assert (await _refused(url, hello(resume="no-such-session")))[0] == "unknown_session"

        connection, welcome = await _open_session(url, camera, credential=phone)
        first = encode_image(images[0].image, 0, images[0].timestamp, "png")
        await connection.send(first.pack())
        await _until(connection, "pose")
        bad = [
            ("{oops", "malformed"),
            ('{"type": "warp"}', "unknown_type"),
            ('{"type": "log", "text": "' + "x" * 70000 + '"}', "oversized"),
            ('{"type": "telemetry", "kind": "imu", "timestamp": 5, "gyro_rad_s": [0, 0, 0], "accel_m_s2": [0, 0, 9.8]}', None),
            ('{"type": "telemetry", "kind": "imu", "timestamp": 4, "gyro_rad_s": [0, 0, 0], "accel_m_s2": [0, 0, 9.8]}', "out_of_order"),
            ('{"type": "pose", "seq": 1, "timestamp": 1, "t": [0, 0, 0], "q": [1, 0, 0, 0], "state": "OK"}', "unknown_type"),
        ]
        for text, code in bad:
            await connection.send(text)
            if code is not None:
                error, _ = await _until(connection, "error")
                assert error.code == code, (text[:40], error)
        corrupt = ImageMessage(1, images[1].timestamp, "jpeg", camera.width, camera.height, b"\xff\xd8" + bytes(range(256)) * 40)
        await connection.send(corrupt.pack())
        error, _ = await _until(connection, "error")
        assert (error.code, error.seq) in (("corrupt_image", 1),)
        await connection.send(encode_image(images[2].image, 0, images[2].timestamp, "png").pack())  # seq repeats (1 was refused: not taken)
        error, _ = await _until(connection, "error")
        assert error.code == "out_of_order"
        await connection.send(encode_image(images[2].image[:100], 3, images[2].timestamp, "png").pack())
        error, _ = await _until(connection, "error")
        assert error.code == "malformed" and "configured camera" in error.message
        await connection.send(encode_image(images[3].image, 4, images[3].timestamp, "png").pack())
        pose, _ = await _until(connection, "pose")  # the session went on
        assert pose.seq == 4
        await connection.send('{"type": "bye"}')
        await connection.close()
        return welcome.session_id, [code for _, code in bad if code]

    with running_station(station_data, paired=True) as station:
        operator = operator_credential(station)
        phone = mobile_credential(station, operator)
        with OperatorFeed(station, operator) as feed:
            session_id, codes = asyncio.run(scenario(station.url, phone))
            feed.event("ended", session_id)
        assert _http_status(f"{station.http}/api/state") == 401  # the operator API needs the operator's credential
        assert _http_status(f"{station.http}/") == 200  # the page itself is public
    store = _store(station_data)
    try:
        logged = [e["code"] for e in store.rows("events", session_id)]
        for code in [*codes, "corrupt_image", "out_of_order"]:
            assert code in logged
        refused = [e["code"] for e in store.recent_events(100) if e["session_id"] is None]
        assert {"bad_token", "bad_version", "not_ready", "unknown_session"} <= set(refused)
        rows = store.rows("frames", session_id)
        assert [r["seq"] for r in rows] == [0, 4] and all(r["estimated"] for r in rows)  # refused frames are not recorded
        mcap = store.session(session_id)["mcap_path"]
    finally:
        store.close()
    assert sum(1 for topic, _, _ in indexed_messages(mcap) if topic.startswith("/camera/image")) == 2


def test_killed_client_leaves_an_interrupted_session_that_resumes(station_data, frames):
    camera, images = frames

    async def first_link(url: str) -> str:
        connection, welcome = await _open_session(url, camera)
        await _stream_until_posed(connection, images[:5], 0)
        connection.transport.abort()  # the phone dies: no close handshake
        return welcome.session_id

    async def second_link(url: str, session_id: str) -> None:
        connection, welcome = await _open_session(url, camera, resume=session_id)
        assert welcome.resumed and welcome.session_id == session_id and welcome.next_seq == 5
        await _stream_until_posed(connection, images[5:9], welcome.next_seq)
        await connection.send('{"type": "bye"}')
        await connection.close()

    with running_station(station_data) as station, OperatorFeed(station) as feed:
        session_id = asyncio.run(first_link(station.url))
        feed.event("interrupted", session_id, timeout=20)
        store = _store(station_data)
        committed(lambda: store.session(session_id)["status"] == "interrupted", "the interrupted status")
        assert len(store.rows("frames", session_id)) == 5 and len(store.rows("poses", session_id)) == 5
        asyncio.run(second_link(station.url, session_id))
        feed.event("ended", session_id)
    try:
        session = store.session(session_id)
        assert session["status"] == "ended"
        assert len(store.rows("frames", session_id)) == 9 and len(store.rows("poses", session_id)) == 9
        assert "resumed" in [e["code"] for e in store.rows("events", session_id)]
        images_recorded = sum(1 for topic, _, _ in indexed_messages(session["mcap_path"]) if topic.startswith("/camera/image"))
        assert images_recorded == 9
    finally:
        store.close()


def test_killed_station_loses_nothing_it_recorded(station_data, frames):
    camera, images = frames

    async def stream(url: str) -> str:
        connection, welcome = await _open_session(url, camera)
        await _stream_until_posed(connection, images[:6], 0)
        return welcome.session_id

    with running_station(station_data) as station:
        session_id = asyncio.run(stream(station.url))
        store = _store(station_data)
        committed(lambda: len(store.rows("frames", session_id)) == len(store.rows("poses", session_id)) == 6, "the six frames and poses")
        store.close()
        station.stop(signal.SIGKILL)
        mcap = next((station_data / "sessions").glob("*.mcap"))
        assert not has_summary(mcap)
    with running_station(station_data):
        pass  # start-up recovery runs before the station listens (uvicorn's lifespan start)
    store = _store(station_data)
    try:
        session = store.session(session_id)
        assert session["status"] == "interrupted"
        assert len(store.rows("frames", session_id)) == 6 and len(store.rows("poses", session_id)) == 6
        assert has_summary(mcap)
        assert sum(1 for topic, _, _ in indexed_messages(mcap) if topic == "/camera/image/compressed") == 6
        assert "recording_repaired" in [e["code"] for e in store.rows("events", session_id)]
    finally:
        store.close()


def test_unresumed_session_is_released_and_resumes_from_disk_with_a_new_map(tmp_path, station_data, frames):
    camera, images = frames
    config = tmp_path / "settings.yaml"
    config.write_text("station:\n  resume_window_s: 1.0\n")

    async def first_link(url: str) -> str:
        connection, welcome = await _open_session(url, camera)
        await _stream_until_posed(connection, images[:3], 0)
        connection.transport.abort()
        return welcome.session_id

    async def second_link(url: str, session_id: str) -> None:
        connection, welcome = await _open_session(url, camera, resume=session_id)
        assert welcome.resumed and welcome.next_seq == 3
        await _stream_until_posed(connection, images[3:6], welcome.next_seq)
        await connection.send('{"type": "bye"}')
        await connection.close()

    with running_station(station_data, "--config", str(config)) as station, OperatorFeed(station) as feed:
        session_id = asyncio.run(first_link(station.url))
        feed.event("released", session_id, timeout=20)
        store = _store(station_data)
        committed(lambda: "released" in [e["code"] for e in store.rows("events", session_id)], "the release")
        assert has_summary(store.session(session_id)["mcap_path"])  # closed when released
        asyncio.run(second_link(station.url, session_id))
        feed.event("ended", session_id)
    try:
        session = store.session(session_id)
        assert session["status"] == "ended"
        assert len(store.rows("frames", session_id)) == 6 and len(store.rows("poses", session_id)) == 6
        assert [r["source"] for r in store.rows("settings", session_id)].count("server") == 2  # a new estimator after the release
        assert sum(1 for topic, _, _ in indexed_messages(session["mcap_path"]) if topic.startswith("/camera/image")) == 6
    finally:
        store.close()


def test_bad_telemetry_gets_specific_events_and_the_session_and_recording_go_on(station_data, frames):
    """Telemetry for the navigation filter (the session gave its IMU extrinsic): NaN refused,
    a clock that jumps, an IMU at an irregular rate, GPS without lock; each is its own event."""
    camera, images = frames
    imu = '{{"type": "telemetry", "kind": "imu", "timestamp": {t}, "gyro_rad_s": [0, 0, 0], "accel_m_s2": [0, 0, {a}]}}'

    async def scenario(url: str) -> str:
        connection = await _connect(url)
        await connection.send(encode(Hello(protocol=PROTOCOL_VERSION, device="test")))
        welcome, _ = await _until(connection, "welcome")
        await connection.send(encode(Config(camera=camera, T_body_cam=[float(v) for v in np.eye(4).reshape(-1)])))
        while (await _until(connection, "status"))[0].state != "running":
            pass
        for k in range(20):  # 100 Hz
            await connection.send(imu.format(t=0.01 * k, a=9.8))
        await connection.send(imu.format(t=0.5, a="NaN"))
        error, _ = await _until(connection, "error")
        assert error.code == "malformed" and "NaN" in error.message
        await connection.send(imu.format(t=0.6, a=9.8))  # 0.41 s after the last: an irregular IMU
        await connection.send(imu.format(t=100.0, a=9.8))  # its clock jumps
        rows = [[100.0 + 0.01 * k, 0, 0, 0, 0, 0, 9.8] for k in (1, 2, 3)]  # then samples sent together
        await connection.send(json.dumps({"type": "telemetry", "kind": "imu_batch", "timestamp": rows[-1][0], "samples": rows}))
        await connection.send(json.dumps({"type": "telemetry", "kind": "imu_batch", "timestamp": rows[-1][0], "samples": rows[1:]}))
        error, _ = await _until(connection, "error")
        assert error.code == "out_of_order"  # a batch starting before the IMU's last sample, single or batched
        await connection.send('{"type": "telemetry", "kind": "gps", "timestamp": 100.0, "latitude_deg": null, "longitude_deg": null}')
        await connection.send(encode_image(images[0].image, 0, images[0].timestamp, "png").pack())
        pose, _ = await _until(connection, "pose")  # the session went on
        assert pose.seq == 0 and pose.gps == "off" and not pose.metric
        await connection.send('{"type": "bye"}')
        await connection.close()
        return welcome.session_id

    with running_station(station_data) as station, OperatorFeed(station) as feed:
        session_id = asyncio.run(scenario(station.url))
        for code in ("imu_gap", "clock_jump", "gps_no_lock"):
            assert feed.event(code, session_id, timeout=30)["level"] == "warning"
        feed.event("ended", session_id)
    store = _store(station_data)
    try:
        logged = [e["code"] for e in store.rows("events", session_id)]
        assert {"malformed", "imu_gap", "clock_jump", "gps_no_lock"} <= set(logged)
        kinds = [r["kind"] for r in store.rows("telemetry", session_id)]
        batches = [r for r in store.rows("telemetry", session_id) if "samples" in json.loads(r["data_json"])]
        assert kinds.count("imu") == 23 and len(batches) == 1 and kinds.count("gps") == 1  # everything that parsed is recorded; a batch is one imu row
        session = store.session(session_id)
    finally:
        store.close()
    topics = [topic for topic, _, _ in indexed_messages(session["mcap_path"])]
    assert topics.count("/imu") == 25 and topics.count("/gps/fix") == 1  # a batch's samples each on /imu
