"""The ``evp`` application: the command groups assembled, and errors mapped to exit codes.

Heavy modules are imported inside each command, so ``evp --help`` is fast. The exit codes are
:class:`evp.errors.ExitCode`'s (0 ok, 1 internal bug, 2 usage, 3 bad input data, 4 link).
"""

from __future__ import annotations

import sys
import traceback

import typer

from evp import __version__
from evp.cli import align, bench, camera, config, dataset, evaluation, experiment, fly, sim, station, sweep, vocabulary, wifi
from evp.errors import EvpError, ExitCode

HELP = """EVP: where is the vehicle, from its phone camera.

Examples:

  evp info data/sample/davis_slider_depth        what a dataset holds

  evp run data/sample/davis_slider_depth --out runs/sample    trajectory + metrics + plots

  evp eval groundtruth.txt estimate.txt --align sim3 --json metrics.json --report report/

  evp calibrate board_images/ --pattern chessboard --cols 9 --rows 7 --square 0.025 --out camera.yaml

  evp convert poses.txt poses.tum --to tum --times times.txt

  evp config dump > settings.yaml
"""

app = typer.Typer(help=HELP, no_args_is_help=True, pretty_exceptions_enable=False, add_completion=False, rich_markup_mode=None)
for group in (dataset, sim, fly, align, evaluation, camera, station, experiment, sweep):
    app.add_typer(group.app)
app.add_typer(config.app, name="config")
app.add_typer(vocabulary.app, name="vocabulary")
app.add_typer(wifi.app, name="wifi")
app.add_typer(bench.app, name="bench")
_state = {"debug": False}


def _version(value: bool) -> None:
    if value:
        typer.echo(f"evp {__version__}")
        raise typer.Exit()


@app.callback()
def _root(
    version: bool = typer.Option(False, "--version", callback=_version, is_eager=True, help="Print the version and exit."),
    debug: bool = typer.Option(False, "--debug", help="Show full tracebacks for errors."),
) -> None:
    _state["debug"] = debug


# the packages of the optional extras (pyproject.toml), by the import name a missing one raises
OPTIONAL_MODULES = {
    **dict.fromkeys(("starlette", "uvicorn", "websockets", "sqlalchemy", "cryptography", "segno"), "station"),
    "pymavlink": "mavlink",
    "psycopg": "postgres",
    **dict.fromkeys(("dask", "distributed"), "cluster"),
}


def main() -> None:
    """Entry point: an :class:`EvpError` becomes one line on stderr and its category's exit code
    (``--debug`` adds the traceback); any other exception is a bug: traceback, exit 1."""
    try:
        app()
    except EvpError as exc:
        if _state["debug"]:
            traceback.print_exc()
        typer.echo(f"error: {exc}", err=True)
        sys.exit(exc.exit_code)
    except ModuleNotFoundError as exc:
        extra = OPTIONAL_MODULES.get((exc.name or "").partition(".")[0])
        if extra is None:
            raise
        typer.echo(
            f"error: this command needs {exc.name}, in EVP's '{extra}' extra: pip install 'evp[{extra}]' (scripts/setup.sh installs every extra)", err=True
        )
        sys.exit(ExitCode.USAGE)
    except Exception:
        traceback.print_exc()
        typer.echo("internal error: the traceback above is a bug in EVP", err=True)
        sys.exit(ExitCode.INTERNAL)
