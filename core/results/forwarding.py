"""Store-and-forward: a factory network goes down, stations keep testing.

The ``sql`` sink commits every record to a local SQLite outbox first (the same schema), then
forwards finished runs to the central store — after every unit, from a background thread, and on
``magline sync``.  Exactly once: a run carries a UUID and the central store's ``run_uuid`` is
unique, so a run forwarded twice (a crash between the central commit and the outbox's mark) is
found and skipped; each run is copied in one central transaction, so a forward interrupted
half-way leaves nothing behind and is simply retried.
"""

from __future__ import annotations

import contextlib
import logging
import threading
import time
from datetime import UTC, datetime
from pathlib import Path
from typing import TYPE_CHECKING, Any

from sqlalchemy import create_engine, func, select, update
from sqlalchemy.exc import IntegrityError, OperationalError, SQLAlchemyError

from magline.core.faults import StationFault
from magline.core.results.sqlite_store import SqliteSink
from magline.core.results.store import RUNNING, SqlStore, reason
from magline.core.results.tables import attachments, attempt_streams, attempts, measurements, params, phases, runs

if TYPE_CHECKING:
    from sqlalchemy import Connection
    from sqlalchemy.engine import URL

    from magline.core.record import AttemptRecord, RunRecord
    from magline.core.results.reading import RunFilter
    from magline.core.results.series import RunSeries

log = logging.getLogger(__name__)

CHILDREN = (phases, attempts, attempt_streams, measurements, params, attachments)
RETRY_S = 30.0  # the background forwarder tries again this often while records are queued
CONNECT_TIMEOUT_S = 3


def _pending() -> Any:
    """Finished runs the outbox has not forwarded yet."""
    return runs.c.forwarded.is_(None) & (runs.c.verdict != RUNNING)


def copy_run(source: Connection, target: Connection, run_id: int) -> bool:
    """Copy one run with everything that hangs off it; False when the target already has it."""
    row = dict(source.execute(select(runs).where(runs.c.id == run_id)).one()._mapping)
    if target.execute(select(runs.c.id).where(runs.c.run_uuid == row["run_uuid"])).first() is not None:
        return False
    new_id = target.execute(runs.insert().values(
        **{k: v for k, v in row.items() if k not in ("id", "forwarded")})).inserted_primary_key[0]
    copy_children(source, target, run_id, new_id)
    return True


def copy_children(source: Connection, target: Connection, run_id: int, new_id: int) -> None:
    for table in CHILDREN:
        rows = [{**dict(r._mapping), "run_id": new_id} for r in source.execute(
            select(table).where(table.c.run_id == run_id))]
        if rows:
            target.execute(table.insert(), rows)


class ForwardingStore:
    """The ``sql`` sink: a local outbox, forwarded to the server named by an environment variable."""

    def __init__(self, outbox: Path, url: URL) -> None:
        self.outbox = SqliteSink(outbox)
        self.url = url
        self.server = url.render_as_string(hide_password=True)
        self.where = f"{self.server} (outbox {outbox})"
        self.last_error: str | None = None
        self._failed_at: float | None = None  # monotonic time of the last failed forward
        self._central: SqlStore | None = None
        self._lock = threading.Lock()
        self._wake = threading.Event()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._forward_in_background, name="magline-forward", daemon=True)
        self._thread.start()

    # -------------------------------------------------------------- the sink protocol (outbox first)
    def begin(self, record: RunRecord) -> None:
        self.outbox.begin(record)

    def save_attempt(self, record: RunRecord, attempt: AttemptRecord) -> None:
        self.outbox.save_attempt(record, attempt)

    def finish(self, record: RunRecord) -> None:
        """Committed to the outbox; forwarded now unless the server failed within the last retry
        period (then the background forwarder keeps trying, and the unit does not wait for it)."""
        self.outbox.finish(record)
        if self._failed_at is not None and time.monotonic() - self._failed_at < RETRY_S:
            self._wake.set()
        else:
            self.forward()

    # -------------------------------------------------------------- which station holds which slot
    def claim_slot(self, holder: dict) -> str | None:
        """Claimed on the server, where every computer of the line sees it.  Unreachable: claimed in
        the outbox only, and said — the line keeps testing through a server outage (the purpose of the
        outbox), with this computer's own lock still holding its slot."""
        central = self.central()
        if central is not None:
            try:
                return central.claim_slot(holder)
            except StationFault as exc:
                self.last_error = str(exc)
        log.warning("slot claimed on this computer only: results server %s unreachable (%s)", self.server,
                    self.last_error)
        return self.outbox.claim_slot(holder)

    def touch_slot(self, holder: dict) -> None:
        for store in (self._central, self.outbox):
            if store is not None:
                with contextlib.suppress(StationFault):
                    store.touch_slot(holder)

    def release_slot(self, holder: dict) -> None:
        for store in (self._central, self.outbox):
            if store is not None:
                with contextlib.suppress(StationFault):
                    store.release_slot(holder)

    def slots_held(self) -> list[dict[str, Any]]:
        central = self.central()
        return central.slots_held() if central is not None else self.outbox.slots_held()

    def location(self, record: RunRecord) -> str:
        with self.outbox.engine.connect() as conn:
            forwarded = conn.execute(select(runs.c.forwarded).where(runs.c.id == record.run_id)).scalar()
        if forwarded:
            return f"{self.server} (forwarded from the outbox, outbox run {record.run_id})"
        return (f"{self.outbox.where} run {record.run_id}, QUEUED for {self.server}: {self.pending()} record(s) "
                f"waiting ({self.last_error or 'not forwarded yet'})")

    def history(self, serial: str) -> list[dict[str, Any]]:
        """Every station's runs from the central store; this station's outbox when it is unreachable."""
        central = self.central()
        return central.history(serial) if central is not None else self.outbox.history(serial)

    def series(self, where: RunFilter, last: int | None = None, names: Any = None,
               with_attempts: bool = False, with_limits: bool = True, first: int | None = None) -> RunSeries:
        """The line's history from the central store; this station's outbox while it is unreachable
        (``source`` says which)."""
        central = self.central()
        if central is not None:
            try:
                return central.series(where, last, names, with_attempts, with_limits, first)
            except StationFault as exc:
                self.last_error = str(exc)
        found = self.outbox.series(where, last, names, with_attempts, with_limits, first)
        found.source = f"this station's outbox {self.outbox.where} (server unreachable)"
        return found

    @property
    def record_engine(self) -> Any:
        """The outbox: the record just written is there whether or not the server is reachable."""
        return self.outbox.engine

    @property
    def engine(self) -> Any:
        central = self.central()
        if central is None:
            raise StationFault(f"results server {self.server} unreachable: {self.last_error}")
        return central.engine

    def close(self) -> None:
        self._stop.set()
        self._wake.set()
        self._thread.join(timeout=CONNECT_TIMEOUT_S * 3)
        if self._central is not None:
            self._central.close()
        self.outbox.close()

    # -------------------------------------------------------------- forwarding
    def central(self) -> SqlStore | None:
        if self._central is None:
            try:
                connect_args = {"connect_timeout": CONNECT_TIMEOUT_S} if self.url.drivername.startswith(
                    "postgresql") else {}
                engine = create_engine(self.url, pool_pre_ping=True, connect_args=connect_args)
                self._central = SqlStore(engine, self.server)
            except StationFault as exc:
                self.last_error = str(exc)
                return None
        return self._central

    def pending(self) -> int:
        with self.outbox.engine.connect() as conn:
            return conn.execute(select(func.count()).select_from(runs).where(_pending())).scalar_one()

    def forward(self) -> tuple[int, int]:
        """Forward every finished run not yet forwarded; (forwarded now, still pending)."""
        with self._lock:
            central = self.central()
            forwarded = 0
            if central is not None:
                reached = True
                try:
                    forwarded = self._forward_all(central)
                    self.last_error, self._failed_at = None, None
                except (SQLAlchemyError, OSError) as exc:
                    self.last_error = f"results server {self.server}: {reason(exc)}"
                    reached = not isinstance(exc, (OperationalError, OSError))  # a run refused, the server there
                if reached:  # what is left, on the station's tile of the line's dashboard
                    with contextlib.suppress(StationFault):
                        central.report_outbox(self._outbox_reports())
            if self.last_error is not None:
                self._failed_at = time.monotonic()
            return forwarded, self.pending()

    def _outbox_reports(self) -> list[dict[str, Any]]:
        """Per station of this outbox: the runs still queued and when the oldest of them finished (after a
        pass that reached the server: what is left is what a later pass will carry).  One grouped read."""
        pending = _pending()
        reported = datetime.now(UTC).isoformat(timespec="seconds")
        with self.outbox.engine.connect() as local:
            rows = local.execute(select(runs.c.station_id, func.count().filter(pending),
                                        func.min(runs.c.finished).filter(pending))
                                 .where(runs.c.station_id.is_not(None)).group_by(runs.c.station_id)).all()
        return [{"station_id": station_id, "reported": reported, "queued": int(queued), "oldest": oldest}
                for station_id, queued, oldest in rows]

    def _forward_all(self, central: SqlStore) -> int:
        done = 0
        with self.outbox.engine.connect() as local:
            ids = [rid for (rid,) in local.execute(select(runs.c.id).where(_pending()).order_by(runs.c.id))]
            for rid in ids:
                try:
                    with central.engine.begin() as target:  # one transaction: all of the run or nothing
                        copied = copy_run(local, target, rid)
                except IntegrityError:  # another forwarder got there first: the run is there
                    copied = False
                with self.outbox.engine.begin() as mark:
                    mark.execute(update(runs).where(runs.c.id == rid).values(
                        forwarded=datetime.now(UTC).isoformat(timespec="seconds")))
                done += int(copied)
        return done

    def _forward_in_background(self) -> None:
        while not self._stop.is_set():
            self._wake.wait(RETRY_S)
            self._wake.clear()
            try:
                self.forward()
            except Exception as exc:  # the station must keep testing whatever the network does
                self.last_error = str(exc)
