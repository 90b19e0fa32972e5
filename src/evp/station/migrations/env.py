"""Alembic's environment for the station database: the caller (evp.station.schema) passes the
connection; no alembic.ini, no logging set-up of its own."""

from alembic import context

context.configure(connection=context.config.attributes["connection"], render_as_batch=True)
with context.begin_transaction():
    context.run_migrations()
