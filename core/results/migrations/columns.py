"""The one shape most of the store's migrations have: nullable columns added to one table.

Why a helper: seven migrations repeated the same batch-alter boilerplate (upgrade adds, downgrade
drops in reverse), and a hand-written downgrade can forget a column.  Here the downgrade is derived
from the upgrade.  Columns are built afresh on each call: a SQLAlchemy ``Column`` belongs to one table,
and a process may migrate several stores (the tests do).
"""

from __future__ import annotations

from collections.abc import Callable

import sqlalchemy as sa
from alembic import op


def added_columns(table: str, **types: sa.types.TypeEngine | type) -> tuple[Callable[[], None], Callable[[], None]]:
    """``(upgrade, downgrade)`` adding the nullable columns ``name=type`` to ``table`` in that order,
    and dropping them in the reverse order (SQLite through Alembic's batch mode)."""

    def upgrade() -> None:
        with op.batch_alter_table(table) as batch:
            for name, kind in types.items():
                batch.add_column(sa.Column(name, kind, nullable=True))

    def downgrade() -> None:
        with op.batch_alter_table(table) as batch:
            for name in reversed(types):
                batch.drop_column(name)

    return upgrade, downgrade
