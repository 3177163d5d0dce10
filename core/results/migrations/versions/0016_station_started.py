"""A station's runs by time: the line's dashboard finds every station and each one's units of the shift
without reading every run (a million runs read in seconds otherwise).

Revision ID: 0016
"""

from __future__ import annotations

from alembic import op

revision = "0016"
down_revision = "0015"


def upgrade() -> None:
    op.create_index("runs_station_started", "runs", ["station_id", "started"])


def downgrade() -> None:
    op.drop_index("runs_station_started", "runs")
