"""Baseline: the schema the hand-written SQLite sink created (magline 0.1, up to 2026-11).

Revision ID: 0001
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "0001"
down_revision = None


def upgrade() -> None:
    op.create_table(
        "runs",
        sa.Column("id", sa.Integer, primary_key=True, autoincrement=True),
        sa.Column("serial", sa.Text, nullable=False), sa.Column("part", sa.Text, nullable=False),
        sa.Column("station_id", sa.Text), sa.Column("line", sa.Text), sa.Column("operator", sa.Text),
        sa.Column("software_version", sa.Text), sa.Column("limit_hash", sa.Text),
        sa.Column("started", sa.Text), sa.Column("finished", sa.Text),
        sa.Column("verdict", sa.Text), sa.Column("cause", sa.Text),
        sa.Column("unit_info", sa.Text), sa.Column("calibration", sa.Text), sa.Column("persistence", sa.Text),
        sa.Column("owner", sa.Text), sa.Column("aborted_phase", sa.Text), sa.Column("left_changed", sa.Text),
        sa.Column("unverified_params", sa.Text), sa.Column("earlier_runs", sa.Integer),
    )
    op.create_index("runs_serial", "runs", ["serial"])
    op.create_table(
        "phases",
        sa.Column("run_id", sa.Integer, sa.ForeignKey("runs.id")), sa.Column("seq", sa.Integer),
        sa.Column("name", sa.Text), sa.Column("outcome", sa.Text), sa.Column("duration_s", sa.Float),
        sa.Column("message", sa.Text), sa.Column("log", sa.Text),
    )
    op.create_table(
        "attempts",
        sa.Column("run_id", sa.Integer, sa.ForeignKey("runs.id")), sa.Column("attempt", sa.Integer),
        sa.Column("samples", sa.Integer), sa.Column("coverage", sa.Float), sa.Column("target", sa.Float),
        sa.Column("accepted", sa.Integer), sa.Column("raw_csv", sa.Text), sa.Column("refused", sa.Text),
        sa.Column("repeats", sa.Integer), sa.Column("sensor_rate_hz", sa.Float),
    )
    op.create_table(
        "measurements",
        sa.Column("run_id", sa.Integer, sa.ForeignKey("runs.id")), sa.Column("name", sa.Text),
        sa.Column("kind", sa.Text), sa.Column("value", sa.Float), sa.Column("unit", sa.Text),
        sa.Column("low", sa.Float), sa.Column("high", sa.Float), sa.Column("verdict", sa.Text),
        sa.Column("data", sa.Text),
    )
    op.create_table(
        "params",
        sa.Column("run_id", sa.Integer, sa.ForeignKey("runs.id")), sa.Column("stage", sa.Text),
        sa.Column("name", sa.Text), sa.Column("value", sa.Float),
    )
    op.create_table(
        "attachments",
        sa.Column("run_id", sa.Integer, sa.ForeignKey("runs.id")), sa.Column("name", sa.Text),
        sa.Column("mime", sa.Text), sa.Column("content", sa.LargeBinary),
    )


def downgrade() -> None:
    for table in ("attachments", "params", "measurements", "attempts", "phases", "runs"):
        op.drop_table(table)
