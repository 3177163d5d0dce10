"""A unit found whatever the case its serial is typed in, and one serial under test once.

``runs_serial_upper`` lets ``history``, ``show`` and ``report`` look a serial up case-folded without
reading every run; ``slot_claims_serial`` makes a second claim of a serial already under test fail in
the database itself, so two computers scanning one label at the same instant cannot both start it.

Revision ID: 0013
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "0013"
down_revision = "0012"


def upgrade() -> None:
    op.create_index("runs_serial_upper", "runs", [sa.text("upper(serial)")])
    claims = sa.table("slot_claims", sa.column("station_id"), sa.column("slot"), sa.column("serial"))
    conn = op.get_bind()
    seen: set[str] = set()
    for row in conn.execute(sa.select(claims).order_by(claims.c.station_id, claims.c.slot)).all():
        if row.serial in seen:  # an older magline let one serial be claimed twice: the first claim keeps it
            conn.execute(sa.delete(claims).where((claims.c.station_id == row.station_id) & (claims.c.slot == row.slot)))
        seen.add(row.serial)
    op.create_index("slot_claims_serial", "slot_claims", ["serial"], unique=True)


def downgrade() -> None:
    op.drop_index("slot_claims_serial", table_name="slot_claims")
    op.drop_index("runs_serial_upper", table_name="runs")
