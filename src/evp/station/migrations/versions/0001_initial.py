"""The station's tables as the first release created them.

Revision ID: 0001
Revises:
"""

import sqlalchemy as sa
from alembic import op

revision = "0001"
down_revision = None


def upgrade() -> None:
    op.create_table(
        "sessions",
        sa.Column("id", sa.String(32), primary_key=True),
        sa.Column("device", sa.String(128), nullable=False),
        sa.Column("started_at", sa.Float, nullable=False),
        sa.Column("ended_at", sa.Float),
        sa.Column("status", sa.String(16), nullable=False),
        sa.Column("camera_json", sa.Text),
        sa.Column("mcap_path", sa.Text),
        sa.Column("frames_received", sa.Integer, nullable=False),
        sa.Column("frames_estimated", sa.Integer, nullable=False),
        sa.Column("frames_dropped", sa.Integer, nullable=False),
    )
    session = lambda nullable: sa.Column("session_id", sa.String(32), sa.ForeignKey("sessions.id"), index=True, nullable=nullable)  # noqa: E731
    key = lambda: sa.Column("id", sa.Integer, primary_key=True, autoincrement=True)  # noqa: E731
    op.create_table(
        "events",
        key(),
        session(True),
        sa.Column("t", sa.Float, nullable=False),
        sa.Column("level", sa.String(8), nullable=False),
        sa.Column("code", sa.String(32), nullable=False),
        sa.Column("text", sa.Text, nullable=False),
    )
    op.create_table(
        "telemetry",
        key(),
        session(False),
        sa.Column("kind", sa.String(8), nullable=False),
        sa.Column("timestamp", sa.Float, nullable=False),
        sa.Column("received_at", sa.Float, nullable=False),
        sa.Column("data_json", sa.Text, nullable=False),
    )
    op.create_table(
        "frames",
        key(),
        session(False),
        sa.Column("seq", sa.Integer, nullable=False),
        sa.Column("timestamp", sa.Float, nullable=False),
        sa.Column("received_at", sa.Float, nullable=False),
        sa.Column("encoding", sa.String(8), nullable=False),
        sa.Column("width", sa.Integer, nullable=False),
        sa.Column("height", sa.Integer, nullable=False),
        sa.Column("size_bytes", sa.Integer, nullable=False),
        sa.Column("estimated", sa.Boolean, nullable=False),
    )
    op.create_table(
        "poses",
        key(),
        session(False),
        sa.Column("seq", sa.Integer, nullable=False),
        sa.Column("timestamp", sa.Float, nullable=False),
        *(sa.Column(name, sa.Float, nullable=False) for name in ("tx", "ty", "tz", "qw", "qx", "qy", "qz")),
        sa.Column("state", sa.String(16), nullable=False),
        sa.Column("quality", sa.Integer, nullable=False),
        sa.Column("reset_counter", sa.Integer, nullable=False),
        sa.Column("processing_ms", sa.Float, nullable=False),
        sa.Column("latency_ms", sa.Float, nullable=False),
    )
    op.create_table(
        "settings",
        key(),
        session(True),
        sa.Column("t", sa.Float, nullable=False),
        sa.Column("source", sa.String(16), nullable=False),
        sa.Column("data_json", sa.Text, nullable=False),
    )


def downgrade() -> None:
    for table in ("settings", "poses", "frames", "telemetry", "events", "sessions"):
        op.drop_table(table)
