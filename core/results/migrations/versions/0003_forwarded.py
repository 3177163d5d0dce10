"""When a run was forwarded from a station's outbox to the central store (NULL: not yet, or a run
written straight into this store).

Revision ID: 0003
"""

from __future__ import annotations

import sqlalchemy as sa

from magline.core.results.migrations.columns import added_columns

revision = "0003"
down_revision = "0002"

upgrade, downgrade = added_columns("runs", forwarded=sa.Text)
