"""Every run gets a UUID: the identity that decides, when records are forwarded between stores,
whether a record is already there (exactly once).

Revision ID: 0002
"""

from __future__ import annotations

import uuid

import sqlalchemy as sa
from alembic import op

revision = "0002"
down_revision = "0001"


def upgrade() -> None:
    with op.batch_alter_table("runs") as batch:
        batch.add_column(sa.Column("run_uuid", sa.String(36), nullable=True))
    bind = op.get_bind()
    runs = sa.table("runs", sa.column("id", sa.Integer), sa.column("run_uuid", sa.String))
    for (rid,) in bind.execute(sa.select(runs.c.id).where(runs.c.run_uuid.is_(None))).all():
        bind.execute(runs.update().where(runs.c.id == rid).values(run_uuid=str(uuid.uuid4())))
    with op.batch_alter_table("runs") as batch:
        batch.alter_column("run_uuid", existing_type=sa.String(36), nullable=False)
        batch.create_unique_constraint("runs_run_uuid", ["run_uuid"])


def downgrade() -> None:
    with op.batch_alter_table("runs") as batch:
        batch.drop_constraint("runs_run_uuid", type_="unique")
        batch.drop_column("run_uuid")
