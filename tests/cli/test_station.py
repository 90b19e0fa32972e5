"""evp serve, evp stream, evp replay: their usage and data errors (the station itself is tested in tests/station)."""

from evp.errors import ExitCode
from tests.cli.conftest import evp
from tests.conftest import SAMPLE


def test_stream_refuses_an_unknown_encoding():
    result = evp("stream", SAMPLE, "--url", "ws://127.0.0.1:9", "--encoding", "gif")
    assert result.returncode == ExitCode.USAGE and "--encoding" in result.stderr


def test_replay_needs_a_station_database_or_a_recording(tmp_path):
    no_database = evp("replay", "abc", "--data", tmp_path)
    assert no_database.returncode == ExitCode.USAGE and "evp.sqlite" in no_database.stderr
    no_recording = evp("replay", tmp_path / "sessions" / "abc.mcap")
    assert no_recording.returncode == ExitCode.DATA and "no such recording" in no_recording.stderr
