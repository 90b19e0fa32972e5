"""``evp config``: the settings, shown."""

from __future__ import annotations

from pathlib import Path

import typer

app = typer.Typer(help="Settings: show the defaults.", no_args_is_help=True)


@app.command("dump")
def config_dump(path: Path | None = typer.Argument(None, help="Settings file to load first (else the defaults).")) -> None:
    """Print the effective settings as YAML."""
    from evp.config import load_settings, settings_yaml

    typer.echo(settings_yaml(load_settings(path)), nl=False)
