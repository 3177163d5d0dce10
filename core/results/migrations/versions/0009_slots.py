"""Parallel slots: the fixture position a unit was tested in, and the id shared by the units that
were calibrated together on one motion (to trace a batch of a gimbal back to its round).

Revision ID: 0009
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "0009"
down_revision = "0008"
branch_labels = None
depends_on = None


def upgrade() -> None:
    with op.batch_alter_table("runs") as batch:
        batch.add_column(sa.Column("slot", sa.Text, nullable=True))
        batch.add_column(sa.Column("slot_group", sa.Text, nullable=True))


def downgrade() -> None:
    with op.batch_alter_table("runs") as batch:
        batch.drop_column("slot_group")
        batch.drop_column("slot")
