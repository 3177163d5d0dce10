"""The results schema, declared once with SQLAlchemy Core for every engine (SQLite, PostgreSQL).

Why Core tables and not ORM objects: a record is written incrementally (the run row first, each
attempt's raw data the moment it exists, the rest at the end) and read by quality tools that
expect plain tables; Core keeps the SQL visible and the same on both engines.  JSON documents
(unit info, calibration, persistence) are stored as text so that any SQL client can read them.
The schema's history lives in ``migrations/`` (Alembic); this module is its current state.
"""

from __future__ import annotations

from sqlalchemy import (
    Column,
    Float,
    ForeignKey,
    Index,
    Integer,
    LargeBinary,
    MetaData,
    String,
    Table,
    Text,
    func,
    text,
)

metadata = MetaData()

runs = Table(
    "runs", metadata,
    Column("id", Integer, primary_key=True, autoincrement=True),
    Column("run_uuid", String(36), nullable=False, unique=True),  # identity across stores (forwarding)
    Column("serial", Text, nullable=False),
    Column("part", Text, nullable=False),
    Column("station_id", Text), Column("line", Text), Column("operator", Text),
    Column("software_version", Text), Column("limit_hash", Text),
    Column("started", Text), Column("finished", Text),
    Column("verdict", Text), Column("cause", Text),
    Column("unit_info", Text), Column("calibration", Text), Column("persistence", Text),
    Column("owner", Text), Column("aborted_phase", Text), Column("left_changed", Text),
    Column("unverified_params", Text), Column("earlier_runs", Integer),
    Column("forwarded", Text),  # when an outbox forwarded this run to the central store
    Column("station_hash", Text), Column("reference_field_ut", Float),
    Column("review", Text), Column("review_note", Text),  # process-review flags (JSON) and what was compared
    Column("slot", Text), Column("slot_group", Text),  # fixture position; units that shared one motion
    Column("field_check", Text),  # the field reference as the unit met it: model, value, last live check (JSON)
    Index("runs_serial", "serial"), Index("runs_part_id", "part", "id"), Index("runs_started", "started"),
    Index("runs_station_started", "station_id", "started"),  # a station's units by time (the dashboard)
    # a station's slots by time (the dashboard's tiles), only runs that have one
    Index("runs_station_slot_started", "station_id", "slot", "started", postgresql_where=text("slot IS NOT NULL"),
          sqlite_where=text("slot IS NOT NULL")),
    Index("runs_running", "id", postgresql_where=text("verdict = 'running'"), sqlite_where=text("verdict = 'running'")),
)
# a serial looked up whatever the case it is typed in (history, show, report)
Index("runs_serial_upper", func.upper(runs.c.serial))

phases = Table(
    "phases", metadata,
    Column("run_id", Integer, ForeignKey("runs.id")), Column("seq", Integer), Column("name", Text),
    Column("outcome", Text), Column("duration_s", Float), Column("message", Text), Column("log", Text),
)

attempts = Table(
    "attempts", metadata,
    Column("run_id", Integer, ForeignKey("runs.id")), Column("attempt", Integer), Column("samples", Integer),
    Column("coverage", Float), Column("target", Float), Column("accepted", Integer),
    Column("raw", LargeBinary),  # the samples as a .npy float32 array (raw_blob)
    Column("refused", Text), Column("repeats", Integer), Column("sensor_rate_hz", Float),
    # why and when the tumble ended, and the running fit's predicted σ then (JSON; see migration 0011)
    Column("stopped", Text), Column("tumble_s", Float), Column("predicted", Text),
)

# The other streams of an attempt: each further magnetometer's readings (``stream`` = "mag:<device id>",
# a raw_blob like attempts.raw) and the accelerometer's ("imu", raw_blob.encode_imu), kept like the primary's.
attempt_streams = Table(
    "attempt_streams", metadata,
    Column("run_id", Integer, ForeignKey("runs.id")), Column("attempt", Integer), Column("stream", Text),
    Column("samples", Integer), Column("raw", LargeBinary),
    Index("attempt_streams_run", "run_id"),
)

measurements = Table(
    "measurements", metadata,
    Column("run_id", Integer, ForeignKey("runs.id")), Column("name", Text), Column("kind", Text),
    Column("value", Float), Column("unit", Text), Column("low", Float), Column("high", Float),
    Column("verdict", Text), Column("data", Text),
)

params = Table(
    "params", metadata,
    Column("run_id", Integer, ForeignKey("runs.id")), Column("stage", Text), Column("name", Text),
    Column("value", Float),
)

attachments = Table(
    "attachments", metadata,
    Column("run_id", Integer, ForeignKey("runs.id")), Column("name", Text), Column("mime", Text),
    Column("content", LargeBinary),
)

# Which station holds which slot right now (core/results/claims.py): one row per claimed (station, slot),
# refreshed while its unit runs, deleted when it ends — one run per slot across computers.
slot_claims = Table(
    "slot_claims", metadata,
    Column("station_id", Text, primary_key=True), Column("slot", Text, primary_key=True),
    Column("host", Text), Column("pid", Integer), Column("serial", Text),
    Column("since", Text), Column("heartbeat", Text),
    Index("slot_claims_serial", "serial", unique=True),  # one serial under test once, across computers
)

# What a station's outbox still held when it last reached the central store (core/results/forwarding.py):
# one row per station, rewritten after every forwarding pass — what the line's dashboard shows on its tile.
station_outbox = Table(
    "station_outbox", metadata,
    Column("station_id", Text, primary_key=True), Column("reported", Text), Column("queued", Integer),
    Column("oldest", Text),  # when the oldest run still queued finished (None: nothing queued)
)

# Frozen control limits (``magline spc --freeze``, AIAG Phase I): a part's process as a baseline of its units
# established it, on one station ("" for every station writing to the store); later units are judged against
# the newest version (Phase II).  Every measurement frozen together shares the version.
control_limits = Table(
    "control_limits", metadata,
    Column("id", Integer, primary_key=True, autoincrement=True),
    Column("part", Text, nullable=False), Column("station_id", Text, nullable=False),
    Column("measurement", Text, nullable=False), Column("version", Integer, nullable=False),
    Column("centre", Float), Column("sigma_within", Float), Column("mr_bar", Float), Column("n", Integer),
    Column("baseline", Text),  # how the baseline was chosen, in words
    Column("first_run", Integer), Column("last_run", Integer),  # the baseline's first and last run ids
    Column("signals", Text),  # JSON: the run rules' signals on the baseline itself [{rule, serial, run_id}]
    Column("frozen_by", Text), Column("frozen_at", Text), Column("software_version", Text),
    Column("acceptance", Text),  # JSON: {"excluded": [serials], "accepted_unstable": bool, "reason": str}
    Index("control_limits_lookup", "part", "station_id", "measurement", "version", unique=True),
)
