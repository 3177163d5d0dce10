"""Several units at once on one fixture: one thread per slot, one shared motion.

Why threads around the one-unit sequencer rather than a second sequencer: every phase, rule and
record of a unit stays exactly what ``magline run`` does for one unit; only the acquisition waits
for the shared motion's round (:mod:`magline.core.sequencer.rounds`).  A slot's fault, refusal
or abort ends that slot's unit and nothing else.  The station-wide objects the slots share (the
results store, the field source and its reference instrument) are called under a lock, so their
writes and instrument sessions never interleave.
"""

from __future__ import annotations

import threading
import uuid
from contextlib import ExitStack
from typing import TYPE_CHECKING, Any

from magline.core.faults import UnitAborted
from magline.core.record import Outcome, RunRecord
from magline.core.sequencer.abort import AbortSwitch
from magline.core.sequencer.hold import claimed_in_store, fixture_locks, holding, unit_locks
from magline.core.serials import clean_serial, one_serial_per_slot

if TYPE_CHECKING:
    from magline.core.sequencer.sequencer import Sequencer
    from magline.core.station.schema import Slot

JOIN_S = 0.2


class Serialized:
    """A shared object whose methods run one at a time (a results store, a field source).

    Each instance's class carries the target's public members, so a capability check
    (``isinstance(store, KeepsSeries)``) answers as for the target: from Python 3.12 a runtime
    Protocol looks members up statically, and a ``__getattr__`` alone would hide them all."""

    def __new__(cls, target: Any) -> Serialized:
        members = {name: property(lambda self, name=name: self.__getattr__(name))
                   for name in dir(target) if not name.startswith("_")}
        return object.__new__(type(cls.__name__, (cls,), members))

    def __init__(self, target: Any) -> None:
        self._target = target
        self._lock = threading.RLock()

    def __getattr__(self, name: str) -> Any:
        value = getattr(self._target, name)
        if not callable(value):
            return value

        def locked(*args: Any, **kwargs: Any) -> Any:
            with self._lock:
                return value(*args, **kwargs)

        return locked


class SlotRunner:
    """Runs the units of a slot station together (``run``: slot id → serial, empty slots left out)."""

    def __init__(self, sequencer: Sequencer) -> None:
        if not sequencer.station.slots:
            raise ValueError(f"station {sequencer.station.station.id} declares no slots")
        self.sequencer = sequencer
        if not isinstance(sequencer.sink, Serialized):
            sequencer.sink = Serialized(sequencer.sink)  # the field source: under sequencer.shared_lock
        self.switches: dict[str, AbortSwitch] = {}

    def run(self, serials: dict[str, str], operator: str = "") -> list[RunRecord]:
        """The records of the slots that held a unit, in the station file's slot order.  A load that
        cannot start — a serial that breaks its rule or names two slots (``SerialRefused``), a slot,
        vehicle, fixture or serial held by another run (``StationBusy``) — is refused whole, before
        any record exists."""
        station = self.sequencer.station
        unknown = [s for s in serials if s not in {slot.id for slot in station.slots}]
        if unknown:
            raise KeyError(f"no slot {unknown[0]!r} on station {station.station.id} "
                           f"(slots: {', '.join(s.id for s in station.slots)})")
        slots = [slot for slot in station.slots if serials.get(slot.id, "").strip()]
        if not slots:
            return []
        cleaned = {slot.id: clean_serial(serials[slot.id], station.slot_product(slot)) for slot in slots}
        one_serial_per_slot(cleaned)
        with ExitStack() as held:
            self._hold(held, slots, cleaned)
            return self._run_load(slots, cleaned, operator)

    def _hold(self, held: ExitStack, slots: list[Slot], serials: dict[str, str]) -> None:
        """The load's locks: the fixture's instruments once, then each slot's own, and each slot's
        claim in the results store (which also refuses a serial under test elsewhere)."""
        seq = self.sequencer
        station = seq.station
        load = seq.holder(", ".join(serials.values()), ", ".join(serials))
        held.enter_context(holding(fixture_locks(station), load))
        for slot in slots:
            holder = seq.holder(serials[slot.id], slot.id)
            held.enter_context(holding(unit_locks(station, seq.station_dir, station.slot_product(slot), slot.id),
                                       holder))
            held.enter_context(claimed_in_store(seq.sink, holder))

    def _run_load(self, slots: list[Slot], serials: dict[str, str], operator: str) -> list[RunRecord]:
        station = self.sequencer.station
        group = str(uuid.uuid4())
        rounds = self.sequencer.rounds([slot.id for slot in slots])
        self.switches = {slot.id: AbortSwitch() for slot in slots}
        records: dict[str, RunRecord] = {}

        finished = {slot.id: threading.Event() for slot in slots}

        def unit(slot: Any) -> None:
            try:
                records[slot.id] = self.sequencer.run_unit(serials[slot.id], operator=operator, slot=slot,
                                                           rounds=rounds, abort=self.switches[slot.id],
                                                           slot_group=group, held=True)
            except BaseException as exc:  # run_unit classifies every fault itself; this is a last guard
                record = RunRecord(serial=serials[slot.id], part=slot.part, station_id=station.station.id,
                                   line=station.station.line, operator=operator, software_version="",
                                   limit_hash="", slot=slot.id, slot_group=group)
                record.verdict, record.cause = Outcome.ERROR, f"slot {slot.id} stopped: {exc}"
                records[slot.id] = record
                rounds.leave(slot.id)
            finally:
                finished[slot.id].set()

        threads = [threading.Thread(target=unit, args=(slot,), name=f"magline-slot-{slot.id}", daemon=True)
                   for slot in slots]
        for thread in threads:
            thread.start()
        # Waited on by events, never by ``Thread.join``/``is_alive``: a signal that interrupts a join can
        # leave the thread looking finished while it still runs (CPython's tstate lock), and the load then
        # returned without the unit's record (KeyError, a traceback on SIGTERM).
        for done in finished.values():
            while not done.is_set():
                try:
                    done.wait(JOIN_S)
                    self._pass_on_abort()
                except UnitAborted as exc:  # Ctrl-C / SIGTERM on the main thread: every slot stops safely
                    self.abort(exc.reason)
        for thread in threads:
            thread.join()  # each has set its event: only its last instructions are left
        return [records[slot.id] for slot in slots]

    def _pass_on_abort(self) -> None:
        requested = self.sequencer.abort.requested
        if requested is not None:
            self.abort(requested)

    def abort(self, reason: str) -> None:
        """Every slot stops at its next safe point (its DUT restored, its record saying aborted)."""
        for switch in self.switches.values():
            if switch.requested is None:
                switch.requested = reason
