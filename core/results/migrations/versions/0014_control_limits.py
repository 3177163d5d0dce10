"""Frozen control limits: what ``magline spc --freeze`` establishes from a baseline (AIAG Phase I) and
every later ``spc`` judges the units against (Phase II), versioned, with who froze them and when.

Revision ID: 0014
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "0014"
down_revision = "0013"


def upgrade() -> None:
    op.create_table(
        "control_limits",
        sa.Column("id", sa.Integer, primary_key=True, autoincrement=True),
        sa.Column("part", sa.Text, nullable=False), sa.Column("station_id", sa.Text, nullable=False),
        sa.Column("measurement", sa.Text, nullable=False), sa.Column("version", sa.Integer, nullable=False),
        sa.Column("centre", sa.Float), sa.Column("sigma_within", sa.Float), sa.Column("mr_bar", sa.Float),
        sa.Column("n", sa.Integer), sa.Column("baseline", sa.Text),
        sa.Column("first_run", sa.Integer), sa.Column("last_run", sa.Integer), sa.Column("signals", sa.Text),
        sa.Column("frozen_by", sa.Text), sa.Column("frozen_at", sa.Text), sa.Column("software_version", sa.Text),
    )
    op.create_index("control_limits_lookup", "control_limits", ["part", "station_id", "measurement", "version"],
                    unique=True)


def downgrade() -> None:
    op.drop_index("control_limits_lookup", table_name="control_limits")
    op.drop_table("control_limits")
