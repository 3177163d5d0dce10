"""The in-run process review: its flags (JSON) and what the unit was compared with.

Revision ID: 0007
"""

from __future__ import annotations

import sqlalchemy as sa

from magline.core.results.migrations.columns import added_columns

revision = "0007"
down_revision = "0006"

upgrade, downgrade = added_columns("runs", review=sa.Text, review_note=sa.Text)
