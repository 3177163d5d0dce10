"""Which station holds which slot: a row per claimed (station, slot) while a unit runs there, so that
two computers given the same station and slot are told apart by the store they share.

Revision ID: 0012
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "0012"
down_revision = "0011"


def upgrade() -> None:
    op.create_table(
        "slot_claims",
        sa.Column("station_id", sa.Text, primary_key=True), sa.Column("slot", sa.Text, primary_key=True),
        sa.Column("host", sa.Text), sa.Column("pid", sa.Integer), sa.Column("serial", sa.Text),
        sa.Column("since", sa.Text), sa.Column("heartbeat", sa.Text),
    )


def downgrade() -> None:
    op.drop_table("slot_claims")
