"""How a frozen baseline was accepted: the units excluded from it and, where it was frozen unstable, the
engineer's reason — kept with the version, beside who froze it.

Revision ID: 0015
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "0015"
down_revision = "0014"


def upgrade() -> None:
    op.add_column("control_limits", sa.Column("acceptance", sa.Text))


def downgrade() -> None:
    op.drop_column("control_limits", "acceptance")
