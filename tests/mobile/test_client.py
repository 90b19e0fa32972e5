"""The Python streaming client against a real ``evp serve`` over loopback TLS: every frame sent
gets its pose back, a resumed session continues at the station's next_seq, an ended session is
final, and a refused token, an unverified certificate or one other than the pinned one is a clear
StreamError; ``evp stream`` exits non-zero when the station refuses frames."""

from __future__ import annotations

import asyncio
import json
import shutil
import subprocess
import sys

import pytest

from evp.mobile.client import StreamClient, StreamError, StreamReport, mobile_url
from evp.mobile.sources import open_source
from evp.station.protocol import Pose
from evp.types import TrackingState
from tests.conftest import SAMPLE
from tests.station.conftest import OperatorFeed, running_station

TOKEN = "m0bile"


@pytest.fixture(scope="module")
def station(tmp_path_factory):
    with running_station(tmp_path_factory.mktemp("mobile") / "station", "--token", TOKEN) as running:
        yield running


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


def _stream(station, frames: int, token: str = TOKEN, resume: str | None = None, trust: dict | None = None, cut_after: int | None = None) -> StreamReport:
    """Stream the sample's first ``frames`` frames, verifying the station's cert.pem unless told otherwise."""
    trust = {"cafile": str(station.data / "tls" / "cert.pem")} if trust is None else trust
    client = StreamClient(station.http, token=token, log=lambda text: None, **trust)
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
    with OperatorFeed(station, TOKEN) as feed:
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
    assert (station.data / "evp.sqlite").stat().st_mode & 0o077 == 0 and station.data.stat().st_mode & 0o077 == 0


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
    command = [sys.executable, "-m", "evp.cli", "stream", str(folder), "--url", station.url, "--token", TOKEN, "--quiet"]
    result = subprocess.run([*command, "--cafile", str(station.data / "tls" / "cert.pem")], capture_output=True, text=True, timeout=120)
    assert result.returncode == 4, result.stderr
    summary = json.loads(result.stdout.strip().splitlines()[-1])
    assert summary["frames_refused"] == 3 and summary["poses_received"] == 0
    assert all(error.startswith("bad_timestamp") and "milliseconds" in error for error in summary["first_errors"])
