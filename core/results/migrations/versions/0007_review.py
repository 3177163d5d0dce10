"""The in-run process review: its flags (JSON) and what the unit was compared with.

Revision ID: 0007
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "0007"
down_revision = "0006"
branch_labels = None
depends_on = None


def upgrade() -> None:
    with op.batch_alter_table("runs") as batch:
        batch.add_column(sa.Column("review", sa.Text, nullable=True))
        batch.add_column(sa.Column("review_note", sa.Text, nullable=True))


def downgrade() -> None:
    with op.batch_alter_table("runs") as batch:
        batch.drop_column("review_note")
        batch.drop_column("review")
