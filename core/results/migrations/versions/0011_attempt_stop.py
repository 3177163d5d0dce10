"""Why and when each attempt's tumble ended, and the uncertainties the running fit predicted then:
``stopped`` ("determined", "samples", "stream ended"), ``tumble_s`` (seconds of tumbling) and
``predicted`` (JSON: per sensor prefix, the predicted σ by measurement name).  Older rows keep NULL.

Revision ID: 0011
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "0011"
down_revision = "0010"
branch_labels = None
depends_on = None


def upgrade() -> None:
    with op.batch_alter_table("attempts") as batch:
        batch.add_column(sa.Column("stopped", sa.Text))
        batch.add_column(sa.Column("tumble_s", sa.Float))
        batch.add_column(sa.Column("predicted", sa.Text))


def downgrade() -> None:
    with op.batch_alter_table("attempts") as batch:
        batch.drop_column("predicted")
        batch.drop_column("tumble_s")
        batch.drop_column("stopped")
