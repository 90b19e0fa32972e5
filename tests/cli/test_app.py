"""evp.cli.app: the assembled application, one-line errors, and the exit code of each category."""

import subprocess
import sys

import pytest

from evp import __version__
from evp.errors import ExitCode
from tests.cli.conftest import evp
from tests.conftest import SAMPLE


def test_version_and_help():
    assert evp("--version").stdout.strip() == f"evp {__version__}"
    out = evp("--help").stdout
    assert "Examples" in out and "evp eval" in out
    for command in ("info", "run", "sim", "align", "formats", "eval", "convert", "calibrate", "camera", "serve", "stream", "replay", "config", "vocabulary"):
        assert f"  {command} " in out


def test_errors_are_one_line_and_debug_shows_traceback(tmp_path):
    result = evp("info", tmp_path / "missing")
    assert result.returncode == ExitCode.DATA
    assert result.stderr.strip().startswith("error:") and len(result.stderr.strip().splitlines()) == 1
    debug = evp("--debug", "info", tmp_path / "missing")
    assert debug.returncode == ExitCode.DATA and "Traceback" in debug.stderr


def test_usage_errors_exit_2(tmp_path):
    assert evp("run", SAMPLE).returncode == ExitCode.USAGE  # click: --out missing
    config = tmp_path / "bad.yaml"
    config.write_text("orb:\n  n_features: 10\n")
    bad_settings = evp("run", SAMPLE, "--out", tmp_path / "o", "--config", config)
    assert bad_settings.returncode == ExitCode.USAGE and "orb.n_features" in bad_settings.stderr
    assert evp("camera", "no_such_profile").returncode == ExitCode.USAGE
    no_map = evp("run", SAMPLE, "--out", tmp_path / "o", "--map", tmp_path / "missing.npz")
    assert no_map.returncode == ExitCode.USAGE and "missing.npz: no such file" in no_map.stderr


def test_data_errors_exit_3(tmp_path):
    broken = tmp_path / "broken.tum"
    broken.write_text("0 1 2 3 not-a-number 0 0 1\n")
    result = evp("convert", broken, tmp_path / "out.tum")
    assert result.returncode == ExitCode.DATA and str(broken) in result.stderr
    not_a_map = tmp_path / "map.npz"
    not_a_map.write_text("not a map")
    result = evp("run", SAMPLE, "--out", tmp_path / "o", "--map", not_a_map)
    assert result.returncode == ExitCode.DATA and "not an EVP map file" in result.stderr


def test_link_errors_exit_4(tmp_path):
    # nothing listens on port 9 of this machine: the connection is refused at once
    result = evp("stream", SAMPLE, "--url", "ws://127.0.0.1:9", "--max-frames", "1", timeout=120)
    assert result.returncode == ExitCode.LINK and "cannot connect" in result.stderr


def test_a_bug_exits_1_with_its_traceback(monkeypatch, capsys):
    import evp.cli.app as cli_app

    def broken_app():
        raise RuntimeError("a bug")

    monkeypatch.setattr(cli_app, "app", broken_app)
    with pytest.raises(SystemExit) as exit_info:
        cli_app.main()
    assert exit_info.value.code == ExitCode.INTERNAL
    err = capsys.readouterr().err
    assert "Traceback" in err and "RuntimeError: a bug" in err and "internal error" in err


def test_the_entry_point_is_the_app_modules_main():
    import tomllib
    from pathlib import Path

    from evp.cli import main

    scripts = tomllib.loads((Path(__file__).resolve().parents[2] / "pyproject.toml").read_text())["project"]["scripts"]
    assert scripts["evp"] == "evp.cli:main" and main.__module__ == "evp.cli.app"


def test_a_missing_optional_extra_is_named(tmp_path):
    """A core-only install (pip install evp) has no station libraries: the command says which
    extra to install, as a usage error, instead of a traceback."""
    blocked = "import sys; sys.modules['sqlalchemy'] = None; from evp.cli import main; main()"
    proc = subprocess.run([sys.executable, "-c", blocked, "replay", "0", "--db", f"sqlite:///{tmp_path}/none.db"], capture_output=True, text=True, timeout=120)
    assert proc.returncode == ExitCode.USAGE, proc.stderr
    assert "'station' extra" in proc.stderr and "evp[station]" in proc.stderr and "Traceback" not in proc.stderr
