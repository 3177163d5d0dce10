"""Every magnetometer of a unit and its accelerometer: the streams an attempt read besides the
primary magnetometer (whose readings stay in ``attempts.raw``), one row per stream.

Revision ID: 0010
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "0010"
down_revision = "0009"


def upgrade() -> None:
    op.create_table(
        "attempt_streams",
        sa.Column("run_id", sa.Integer, sa.ForeignKey("runs.id")), sa.Column("attempt", sa.Integer),
        sa.Column("stream", sa.Text), sa.Column("samples", sa.Integer), sa.Column("raw", sa.LargeBinary),
    )
    op.create_index("attempt_streams_run", "attempt_streams", ["run_id"])


def downgrade() -> None:
    op.drop_index("attempt_streams_run", "attempt_streams")
    op.drop_table("attempt_streams")
