"""What the line's dashboard shows of a station beyond its runs: the field reference each unit met (model,
value, the live fluxgate's last check) and how many records the station's outbox still held when it last
reached the central store.

Revision ID: 0017
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "0017"
down_revision = "0016"


def upgrade() -> None:
    op.add_column("runs", sa.Column("field_check", sa.Text))
    op.create_table(
        "station_outbox",
        sa.Column("station_id", sa.Text, primary_key=True), sa.Column("reported", sa.Text),
        sa.Column("queued", sa.Integer), sa.Column("oldest", sa.Text),
    )


def downgrade() -> None:
    op.drop_table("station_outbox")
    # plain SQL, not a batch: SQLite's batch copies the table and loses its expression index on upper(serial)
    op.execute("ALTER TABLE runs DROP COLUMN field_check")
