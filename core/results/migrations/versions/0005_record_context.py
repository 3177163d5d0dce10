"""What judged the unit: the station file's content hash and the field reference used.

Revision ID: 0005
"""

from __future__ import annotations

import sqlalchemy as sa

from magline.core.results.migrations.columns import added_columns

revision = "0005"
down_revision = "0004"

upgrade, downgrade = added_columns("runs", station_hash=sa.Text, reference_field_ut=sa.Float)
