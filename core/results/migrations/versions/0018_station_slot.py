"""A station's slots by time: the line's dashboard finds the fixture positions a station used lately with a
few index probes (reading the station's fortnight of runs took half a second over ten stations of a
million-run store).  Partial: only runs with a slot are in it, so a station without slots adds nothing.

Revision ID: 0018
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "0018"
down_revision = "0017"


def upgrade() -> None:
    op.create_index("runs_station_slot_started", "runs", ["station_id", "slot", "started"],
                    postgresql_where=sa.text("slot IS NOT NULL"), sqlite_where=sa.text("slot IS NOT NULL"))


def downgrade() -> None:
    op.drop_index("runs_station_slot_started", "runs")
