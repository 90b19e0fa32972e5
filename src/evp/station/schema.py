"""The station database's schema version: Alembic migrations run when a store opens it.

``upgrade`` brings any database to the newest version (``migrations/versions``): a new one is
created from nothing, one made before versions existed (the tables, no ``alembic_version``) is
recognised as version 0001 and upgraded from there. ``open_engine`` turns what a user gives as
``--db`` into an engine or one clear line (a missing driver, an unreachable server).
"""

from __future__ import annotations

from pathlib import Path

from sqlalchemy import create_engine, inspect, text
from sqlalchemy.engine import Engine, make_url
from sqlalchemy.exc import ArgumentError, NoSuchModuleError, OperationalError

from evp.errors import ConfigError

MIGRATIONS = Path(__file__).parent / "migrations"
UNVERSIONED = "0001"  # what a database created before schema versions holds


def open_engine(url: str) -> Engine:
    """An engine for ``url``; ``postgresql://`` means the ``postgres`` extra's driver (psycopg 3)."""
    try:
        parsed = make_url(url)
    except ArgumentError as exc:
        raise ConfigError(f"--db {url!r}: not a database URL ({exc})") from None
    if parsed.drivername == "postgresql":
        parsed = parsed.set(drivername="postgresql+psycopg")
    try:
        options = {"pool_pre_ping": True} if parsed.get_backend_name() != "sqlite" else {}
        return create_engine(parsed, future=True, **options)
    except (ModuleNotFoundError, NoSuchModuleError) as exc:
        extra = " (pip install 'evp[postgres]')" if parsed.get_backend_name() == "postgresql" else ""
        raise ConfigError(f"--db {parsed.render_as_string(hide_password=True)}: the database driver is not installed{extra}: {exc}") from None


def health(engine: Engine) -> str | None:
    """None when the database answers a query, else why not (one line)."""
    try:
        with engine.connect() as connection:
            connection.execute(text("SELECT 1"))
    except OperationalError as exc:
        return f"{engine.url.render_as_string(hide_password=True)}: {str(exc.orig).strip().splitlines()[0]}"
    return None


def _alembic_config(connection):
    from alembic.config import Config

    config = Config()
    config.set_main_option("script_location", str(MIGRATIONS))
    config.attributes["connection"] = connection
    return config


def upgrade(engine: Engine) -> str:
    """Migrate the database to the newest schema version; returns that version."""
    from alembic import command

    problem = health(engine)
    if problem is not None:
        raise ConfigError(f"cannot open the station database {problem}")
    with engine.begin() as connection:
        config = _alembic_config(connection)
        tables = set(inspect(connection).get_table_names())
        if "sessions" in tables and "alembic_version" not in tables:
            command.stamp(config, UNVERSIONED)
        command.upgrade(config, "head")
    return version(engine)


def version(engine: Engine) -> str | None:
    from alembic.migration import MigrationContext

    with engine.connect() as connection:
        return MigrationContext.configure(connection).get_current_revision()


def head() -> str:
    from alembic.script import ScriptDirectory

    return ScriptDirectory.from_config(_alembic_config(None)).get_current_head()
