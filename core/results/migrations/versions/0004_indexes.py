"""Indexes for the queries a factory store answers: a run's rows (history, show, export), and a
part's latest runs (the statistics' "last N units of a part").

Revision ID: 0004
"""

from __future__ import annotations

from alembic import op

revision = "0004"
down_revision = "0003"

INDEXES = (("phases_run", "phases", ["run_id"]), ("attempts_run", "attempts", ["run_id"]),
           ("measurements_run", "measurements", ["run_id"]), ("params_run", "params", ["run_id"]),
           ("attachments_run", "attachments", ["run_id"]), ("runs_part_id", "runs", ["part", "id"]),
           ("runs_started", "runs", ["started"]))


def upgrade() -> None:
    for name, table, columns in INDEXES:
        op.create_index(name, table, columns)


def downgrade() -> None:
    for name, table, _ in INDEXES:
        op.drop_index(name, table_name=table)
