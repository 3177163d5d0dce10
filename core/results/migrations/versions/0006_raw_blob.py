"""Raw samples as binary arrays: ``attempts.raw`` (a ``.npy`` float32 blob) replaces ``raw_csv`` text.

Every stored attempt is converted in place (CSV parsed, blob written) in batches, so a store of
any size is upgraded without holding it in memory.  A CSV that cannot be parsed is kept, as a blob
of its UTF-8 text (``raw_blob.decode`` refuses it with a clear message) — a migration never drops
data it does not understand.

Revision ID: 0006
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

from magline.core.fit.samples_csv import SampleFileError, format_samples, parse_samples
from magline.core.results import raw_blob

revision = "0006"
down_revision = "0005"

BATCH = 500


def _attempts(raw_type: sa.types.TypeEngine, name: str) -> sa.Table:
    return sa.table("attempts", sa.column("run_id", sa.Integer), sa.column("attempt", sa.Integer),
                    sa.column(name, raw_type))


def _convert(source: str, target: str, fn) -> None:
    conn = op.get_bind()
    read = _attempts(sa.Text if source == "raw_csv" else sa.LargeBinary, source)
    write = _attempts(sa.LargeBinary if target == "raw" else sa.Text, target)
    last = (-1, -1)
    while True:
        rows = conn.execute(sa.select(read.c.run_id, read.c.attempt, read.c[source])
                            .where(sa.tuple_(read.c.run_id, read.c.attempt) > sa.tuple_(*last))
                            .order_by(read.c.run_id, read.c.attempt).limit(BATCH)).fetchall()
        if not rows:
            return
        for run_id, attempt, value in rows:
            if value is not None:
                conn.execute(sa.update(write).where((write.c.run_id == run_id) & (write.c.attempt == attempt))
                             .values({target: fn(value)}))
        last = (rows[-1][0], rows[-1][1])


def _to_blob(text: str) -> bytes:
    try:
        return raw_blob.encode(parse_samples(text, "stored attempt"))
    except SampleFileError:
        return text.encode("utf-8")


def _to_csv(blob: bytes) -> str:
    try:
        return format_samples(raw_blob.decode(bytes(blob)))
    except raw_blob.RawBlobError:
        return bytes(blob).decode("utf-8", errors="replace")


def upgrade() -> None:
    with op.batch_alter_table("attempts") as batch:
        batch.add_column(sa.Column("raw", sa.LargeBinary, nullable=True))
    _convert("raw_csv", "raw", _to_blob)
    with op.batch_alter_table("attempts") as batch:
        batch.drop_column("raw_csv")


def downgrade() -> None:
    with op.batch_alter_table("attempts") as batch:
        batch.add_column(sa.Column("raw_csv", sa.Text, nullable=True))
    _convert("raw", "raw_csv", _to_csv)
    with op.batch_alter_table("attempts") as batch:
        batch.drop_column("raw")
