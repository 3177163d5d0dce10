"""What judged the unit: the station file's content hash and the field reference used.

Revision ID: 0005
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "0005"
down_revision = "0004"
branch_labels = None
depends_on = None


def upgrade() -> None:
    with op.batch_alter_table("runs") as batch:
        batch.add_column(sa.Column("station_hash", sa.Text, nullable=True))
        batch.add_column(sa.Column("reference_field_ut", sa.Float, nullable=True))


def downgrade() -> None:
    with op.batch_alter_table("runs") as batch:
        batch.drop_column("reference_field_ut")
        batch.drop_column("station_hash")
