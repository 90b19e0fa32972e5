"""The Python streaming client against a real ``evp serve`` over loopback TLS: every frame sent
gets its pose back, a resumed session continues its numbering, and a refused token or a
certificate other than the pinned one is a clear StreamError; pairing keeps the device's
credential in a file only its owner reads."""

from __future__ import annotations

import asyncio
import itertools

import pytest

from evp.mobile.client import StreamClient, StreamError, StreamReport, mobile_url
from evp.mobile.pairing import device_credential
from evp.mobile.sources import open_source
from evp.station.protocol import Pose
from evp.types import TrackingState
from tests.conftest import SAMPLE
from tests.station.conftest import OperatorFeed, http_json, operator_credential, running_station

CREDENTIALS: dict[str, str] = {}  # the module station's operator and paired device


@pytest.fixture(scope="module")
def station(tmp_path_factory):
    folder = tmp_path_factory.mktemp("mobile")
    with running_station(folder / "station", paired=True) as running:
        CREDENTIALS["operator"] = operator_credential(running)
        code = http_json(running, "POST", "/api/pairing", {"role": "mobile"}, credential=CREDENTIALS["operator"])[1]["code"]
        CREDENTIALS["device"] = device_credential(running.url, code, folder / "credentials" / "station")
        yield running


def test_pairing_keeps_the_credential_private_and_reuses_it(station, tmp_path):
    kept = next((p for p in station.data.parent.glob("credentials/*")), None)
    assert kept is not None and kept.stat().st_mode & 0o077 == 0 and kept.read_text() == CREDENTIALS["device"]
    assert device_credential(station.url, None, kept) == CREDENTIALS["device"]  # later runs read it
    assert device_credential(station.url, None, tmp_path / "none") == ""  # none kept: the station will say bad_token
    with pytest.raises(StreamError, match="refused the pairing code"):
        device_credential(station.url, "used-or-made-up", tmp_path / "other")


def _stream(url: str, frames: range, token: str | None = None, resume: str | None = None, fingerprint: str | None = None) -> StreamReport:
    """Stream the sample's ``frames`` (a resumed session goes on from where its link ended)."""
    client = StreamClient(url, token=CREDENTIALS["device"] if token is None else token, fingerprint=fingerprint, log=lambda text: None)
    source = open_source(str(SAMPLE), max_frames=frames.stop)
    source.items = itertools.islice(source.items, frames.start, None)
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


def test_every_frame_gets_its_pose_and_a_resume_continues_the_numbering(station):
    with OperatorFeed(station, CREDENTIALS["operator"]) as feed:
        report = _stream(station.http, range(12))
        assert report.session_id and report.fingerprint and len(report.fingerprint) == 95  # SHA-256, colon separated
        assert report.frames_sent == 12 and sorted(report.poses) == list(range(12)) and not report.errors
        assert all(isinstance(p, Pose) for p in report.poses.values()) and set(report.latency_ms) == set(range(12))
        summary = report.summary()
        assert (summary["poses_received"], summary["frames_dropped"], summary["errors"]) == (12, 0, 0)
        assert summary["poses_tracked"] == sum(TrackingState(p.state).tracked for p in report.poses.values()) > 0
        feed.event("ended", report.session_id)  # the station has closed the session: it can be resumed
        again = _stream(station.http, range(12, 16), resume=report.session_id, fingerprint=report.fingerprint)
        assert again.session_id == report.session_id and sorted(again.poses) == list(range(12, 16)) and not again.errors


def test_a_wrong_token_or_an_unpinned_certificate_is_a_stream_error(station):
    with pytest.raises(StreamError, match="station refused the stream: bad_token"):
        _stream(station.url, range(2), token="wrong")
    with pytest.raises(StreamError, match="is not the pinned"):
        _stream(station.url, range(2), fingerprint="00:" * 31 + "00")
