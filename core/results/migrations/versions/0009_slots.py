"""Parallel slots: the fixture position a unit was tested in, and the id shared by the units that
were calibrated together on one motion (to trace a batch of a gimbal back to its round).

Revision ID: 0009
"""

from __future__ import annotations

import sqlalchemy as sa

from magline.core.results.migrations.columns import added_columns

revision = "0009"
down_revision = "0008"

upgrade, downgrade = added_columns("runs", slot=sa.Text, slot_group=sa.Text)
