"""The Python streaming client against a real ``evp serve`` over loopback TLS: every frame sent
gets its pose back, a resumed session continues at the station's next_seq, an ended session is
final, and a refused credential, an unverified certificate or one other than the pinned one is a
clear StreamError; pairing keeps the device's credential in a file only its owner reads;
``evp stream`` exits non-zero when the station refuses frames."""

from __future__ import annotations

import asyncio
import json
import shutil
import subprocess
import sys

import numpy as np
import pytest

from evp.mobile.client import IMU_BATCH_SPAN_S, StreamClient, StreamError, StreamReport, mobile_url
from evp.mobile.pairing import device_credential
from evp.mobile.sources import StreamSource, open_source
from evp.station.protocol import Pose, decode_image, decode_text
from evp.types import CameraModel, Frame, ImuSample, TrackingState
from tests.conftest import SAMPLE
from tests.station.conftest import OperatorFeed, http_json, operator_credential, running_station, station_database

CREDENTIALS: dict[str, str] = {}  # the module station's operator and paired device


@pytest.fixture(scope="module")
def station(tmp_path_factory):
    folder = tmp_path_factory.mktemp("mobile")
    with running_station(folder / "station", paired=True) as running:
        CREDENTIALS["operator"] = operator_credential(running)
        code = http_json(running, "POST", "/api/pairing", {"role": "mobile"}, credential=CREDENTIALS["operator"])[1]["code"]
        CREDENTIALS["device"] = device_credential(running.url, code, folder / "credentials" / "station", _cafile(running))
        yield running


def _cafile(station) -> str:
    return str(station.data / "tls" / "cert.pem")


class LinkDied(Exception):
    pass


def _cut_after(items, frames: int):
    """The source's items until ``frames`` frames were given, then the link dies (no bye)."""
    given = 0
    for item in items:
        if hasattr(item, "image"):
            if given == frames:
                raise LinkDied
            given += 1
        yield item


def test_pairing_keeps_the_credential_private_and_reuses_it(station, tmp_path):
    kept = next((p for p in station.data.parent.glob("credentials/*")), None)
    assert kept is not None and kept.stat().st_mode & 0o077 == 0 and kept.read_text() == CREDENTIALS["device"]
    assert device_credential(station.url, None, kept) == CREDENTIALS["device"]  # later runs read it
    assert device_credential(station.url, None, tmp_path / "none") == ""  # none kept: the station will say bad_token
    with pytest.raises(StreamError, match="refused the pairing code"):
        device_credential(station.url, "used-or-made-up", tmp_path / "other", _cafile(station))
    with pytest.raises(StreamError, match="pairing with .* failed"):  # the pairing verifies the certificate as the stream does
        device_credential(station.url, "used-or-made-up", tmp_path / "other")


def _stream(station, frames: int, token: str | None = None, resume: str | None = None, trust: dict | None = None, cut_after: int | None = None) -> StreamReport:
    """Stream the sample's first ``frames`` frames, verifying the station's cert.pem unless told otherwise."""
    trust = {"cafile": _cafile(station)} if trust is None else trust
    client = StreamClient(station.http, token=CREDENTIALS["device"] if token is None else token, log=lambda text: None, **trust)
    source = open_source(str(SAMPLE), max_frames=frames)
    if cut_after is not None:
        source.items = _cut_after(source.items, cut_after)
    return asyncio.run(client.run(source, realtime=False, encoding="png", resume=resume))


@pytest.mark.parametrize(
    "typed, url",
    [
        ("127.0.0.1:8443", "wss://127.0.0.1:8443/ws/mobile"),
        ("https://station.local:8443/", "wss://station.local:8443/ws/mobile"),
        ("http://10.0.0.2:8000", "ws://10.0.0.2:8000/ws/mobile"),
        ("wss://10.0.0.2:8443/custom?x=1", "wss://10.0.0.2:8443/custom?x=1"),
    ],
)
def test_the_station_url_a_user_types_becomes_the_mobile_endpoint(typed, url):
    assert mobile_url(typed) == url


def test_a_url_that_is_not_a_station_is_refused():
    with pytest.raises(StreamError, match="must be ws://, wss://, http:// or https://"):
        mobile_url("ftp://10.0.0.2/")


def test_every_frame_gets_its_pose(station):
    report = _stream(station, 12)
    assert report.session_id and report.fingerprint and len(report.fingerprint) == 95  # SHA-256, colon separated
    assert report.frames_sent == 12 and sorted(report.poses) == list(range(12)) and not report.errors
    assert all(isinstance(p, Pose) for p in report.poses.values()) and set(report.latency_ms) == set(range(12))
    summary = report.summary()
    assert (summary["poses_received"], summary["frames_dropped"], summary["errors"]) == (12, 0, 0)
    assert summary["poses_tracked"] == sum(TrackingState(p.state).tracked for p in report.poses.values()) > 0


def test_a_resume_continues_at_the_stations_next_seq_and_an_ended_session_is_final(station):
    """Finding 7: --resume re-sent from frame 0 (124 refusals, recorded anyway); an ended session
    could be resumed."""
    with OperatorFeed(station, CREDENTIALS["operator"]) as feed:
        with pytest.raises(LinkDied):
            _stream(station, 12, cut_after=5)
        interrupted = feed.event("interrupted", timeout=30)["session_id"]
        again = _stream(station, 12, resume=interrupted, trust={"fingerprint": _fingerprint(station)})
        assert again.session_id == interrupted and not again.errors and again.frames_refused == 0
        assert again.frames_skipped == 5 and again.frames_sent == 7
        answered = [seq for seq in [*again.poses, *again.dropped] if seq >= 5]  # frames 3, 4 were in flight when the link died
        assert sorted(answered) == list(range(5, 12)) and again.poses
        feed.event("ended", interrupted)
    with pytest.raises(StreamError, match="session_ended"):
        _stream(station, 2, resume=interrupted)


def _fingerprint(station) -> str:
    from evp.station.tls import fingerprint

    return fingerprint(station.data / "tls" / "cert.pem")


def test_a_wrong_token_or_an_unverified_or_unpinned_certificate_is_a_stream_error(station):
    with pytest.raises(StreamError, match="station refused the stream: bad_token"):
        _stream(station, 2, token="wrong")
    with pytest.raises(StreamError, match="certificate is not trusted"):  # verified by default
        _stream(station, 2, trust={})
    with pytest.raises(StreamError, match="is not the pinned"):
        _stream(station, 2, trust={"fingerprint": "00:" * 31 + "00"})
    assert not _stream(station, 2, trust={"insecure": True}).errors


def test_the_station_certificate_is_a_short_lived_leaf(station):
    import datetime

    from cryptography import x509

    certificate = x509.load_pem_x509_certificate((station.data / "tls" / "cert.pem").read_bytes())
    assert not certificate.extensions.get_extension_for_class(x509.BasicConstraints).value.ca
    assert certificate.not_valid_after_utc - certificate.not_valid_before_utc <= datetime.timedelta(days=91)
    assert (station.data / "tls" / "key.pem").stat().st_mode & 0o077 == 0
    assert station.data.stat().st_mode & 0o077 == 0
    if station_database(station.data).startswith("sqlite"):
        assert (station.data / "evp.sqlite").stat().st_mode & 0o077 == 0


def test_evp_stream_exits_non_zero_when_frames_are_refused(station, tmp_path):
    """Findings 4 and 7: a phone's clock in milliseconds (>= 2^31 s) is refused frame by frame with
    bad_timestamp (it overflowed the recording and closed the link), and evp stream says so."""
    folder = tmp_path / "milliseconds"
    (folder / "images").mkdir(parents=True)
    images = sorted((SAMPLE / "images").iterdir())[:3]
    for image in images:
        shutil.copy(image, folder / "images" / image.name)
    shutil.copy(SAMPLE / "calib.txt", folder / "calib.txt")
    (folder / "images.txt").write_text("".join(f"{1.7e12 + 33 * k:.0f} images/{image.name}\n" for k, image in enumerate(images)))
    command = [
        sys.executable,
        "-m",
        "evp.cli",
        "stream",
        str(folder),
        "--url",
        station.url,
        "--credential-file",
        str(station.data.parent / "credentials" / "station"),
        "--quiet",
    ]
    result = subprocess.run([*command, "--cafile", _cafile(station)], capture_output=True, text=True, timeout=120)
    assert result.returncode == 4, result.stderr
    summary = json.loads(result.stdout.strip().splitlines()[-1])
    assert summary["frames_refused"] == 3 and summary["poses_received"] == 0
    assert all(error.startswith("bad_timestamp") and "milliseconds" in error for error in summary["first_errors"])


class _Sent:
    """A connection that keeps what is sent: text messages decoded, frames as their seq."""

    def __init__(self):
        self.messages: list = []

    async def send(self, data) -> None:
        self.messages.append(decode_text(data) if isinstance(data, str) else ("frame", decode_image(data).seq))


def test_imu_samples_go_together_before_the_frame_that_follows_them():
    """A 200 Hz IMU sent a message a sample was most of the station's event loop: the samples go
    as one imu_batch a frame period, each before the frame after it, and none waits longer than
    IMU_BATCH_SPAN_S (and a sample) when no frame comes."""
    imu = [ImuSample(0.005 * k, (0.0, 0.0, 0.1), (0.0, 0.0, 9.8)) for k in range(60)]  # 0 to 0.295 s
    frames = [Frame(t, np.zeros((8, 8), np.uint8)) for t in (0.0125, 0.0458)]  # then no frame after 0.05 s
    items = sorted([*imu, *frames], key=lambda item: item.timestamp)
    source = StreamSource("test", CameraModel(8, 8, 10.0, 10.0, 4.0, 4.0), 30.0, iter(items), live=False, lossless=True, skipped=[])
    client, sent = StreamClient("ws://127.0.0.1:1", log=lambda text: None), _Sent()

    async def run() -> None:
        receiver = asyncio.create_task(asyncio.sleep(60))
        await client._send_items(sent, source, realtime=False, encoding="png", jpeg_quality=90, max_in_flight=10, receiver=receiver)
        receiver.cancel()

    asyncio.run(run())
    kinds = [m if isinstance(m, tuple) else m.kind for m in sent.messages]
    assert kinds[:4] == ["imu_batch", ("frame", 0), "imu_batch", ("frame", 1)]
    batches = [m for m in sent.messages if not isinstance(m, tuple)]
    rows = [row for batch in batches for row in batch.samples]
    assert [row[0] for row in rows] == [s.timestamp for s in imu]  # every sample once, in order
    assert all(row[0] < 0.0125 for row in batches[0].samples) and all(0.0125 <= row[0] < 0.0458 for row in batches[1].samples)
    period = 0.005
    assert all(batch.samples[-1][0] - batch.samples[0][0] <= IMU_BATCH_SPAN_S + period + 1e-9 for batch in batches)
    assert client.report.telemetry_sent == len(imu) and client.report.frames_sent == 2
