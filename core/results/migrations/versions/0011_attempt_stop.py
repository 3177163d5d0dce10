"""Why and when each attempt's tumble ended, and the uncertainties the running fit predicted then:
``stopped`` ("determined", "samples", "stream ended"), ``tumble_s`` (seconds of tumbling) and
``predicted`` (JSON: per sensor prefix, the predicted σ by measurement name).  Older rows keep NULL.

Revision ID: 0011
"""

from __future__ import annotations

import sqlalchemy as sa

from magline.core.results.migrations.columns import added_columns

revision = "0011"
down_revision = "0010"

upgrade, downgrade = added_columns("attempts", stopped=sa.Text, tumble_s=sa.Float, predicted=sa.Text)
