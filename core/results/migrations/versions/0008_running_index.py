"""A partial index on the runs still ``running``: every store opening looks for runs whose writer
died (to mark them incomplete), and without it that look is a scan of every run ever stored.

Revision ID: 0008
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "0008"
down_revision = "0007"

RUNNING = sa.text("verdict = 'running'")


def upgrade() -> None:
    op.create_index("runs_running", "runs", ["id"], postgresql_where=RUNNING, sqlite_where=RUNNING)


def downgrade() -> None:
    op.drop_index("runs_running", table_name="runs")
