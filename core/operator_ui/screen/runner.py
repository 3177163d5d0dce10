"""Runs one unit at a time for the station screen, on a worker thread, with the same sequencer
``magline run`` uses.  Abort is the sequencer's own switch: honoured at the next safe point, the
DUT restored and closed, the record saying aborted."""

from __future__ import annotations

import threading
from typing import TYPE_CHECKING, Any

from magline.core.faults import UnitAborted
from magline.core.operator_ui.screen.shift_store import ShiftFromStore
from magline.core.operator_ui.screen.state import ScreenState
from magline.core.sequencer.hold import StationBusy
from magline.core.serials import Refused, SerialRefused, clean_serial, known_part, one_serial_per_slot

if TYPE_CHECKING:
    from magline.core.sequencer import Sequencer


class Busy(Exception):
    """A unit is under test already."""


# After its verdict is on the screen a unit's thread still closes the link and re-reads the station's
# standing: an operator scans the next unit at once. A scan then waits this long for that wind-down
# rather than being refused as "under test" under a verdict that says the unit is done.
WIND_DOWN_S = 30.0


class UnitRunner:
    def __init__(self, sequencer: Sequencer, state: ScreenState) -> None:
        self.sequencer = sequencer
        self.state = state
        self._thread: threading.Thread | None = None
        self._lock = threading.Lock()
        self._slots = None  # the slot runner, made on the first load of a slot station
        self.shift = ShiftFromStore(sequencer.station, sequencer.sink, state)
        self.standing()
        self.shift.follow()

    def start(self, serial: str, part: str | None, operator: str = "") -> None:
        station = self.sequencer.station
        if part is not None:
            known_part(part, list(station.products), station.station.id)
        serial = clean_serial(serial, station.products[part or self.state.state["station"]["default_part"]])
        with self._lock:
            self._wait_for_wind_down()
            if self._thread is not None and self._thread.is_alive():
                current = (self.state.state.get("run") or {}).get("serial") or "a unit"
                raise Busy(f"{serial} was not started: {current} is under test — finish or abort it first")
            part = part or self.state.state["station"]["default_part"]
            self.sequencer.abort.clear()
            self.state.unit_started(serial, part)
            self._thread = threading.Thread(target=self._run, args=(serial, part, operator), name="magline-unit",
                                            daemon=True)
            self._thread.start()

    def start_slots(self, serials: dict[str, str], operator: str = "") -> None:
        """A load of a slot station: slot id → serial (empty slots left out), run together."""
        station = self.sequencer.station
        if not station.slots:
            raise ValueError(f"station {station.station.id} has no slots: scan one serial")
        known = {s.id: s.part for s in station.slots}
        unknown = [s for s in serials if s not in known]
        if unknown:
            raise ValueError(f"no slot {unknown[0]!r} on this station (slots: {', '.join(known)})")
        load = {}
        for slot in known:  # in the station's slot order: a repeated label is said for the later slot
            if (serials.get(slot) or "").strip():
                try:
                    load[slot] = clean_serial(serials[slot], station.slot_product(station.slot(slot)))
                except SerialRefused as exc:
                    exc.slot = slot
                    raise
        if not load:
            raise ValueError("scan the serial of at least one slot's unit")
        one_serial_per_slot(load)
        with self._lock:
            self._wait_for_wind_down()
            if self._thread is not None and self._thread.is_alive():
                raise Busy("units are under test: wait for their verdicts or abort them")
            self.sequencer.abort.clear()
            self.state.slots_started(load, {slot: known[slot] for slot in load})
            self._thread = threading.Thread(target=self._run_slots, args=(load, operator), name="magline-load",
                                            daemon=True)
            self._thread.start()

    def _run_slots(self, load: dict[str, str], operator: str) -> None:
        from magline.core.sequencer.slots import SlotRunner

        try:
            if self._slots is None:
                self._slots = SlotRunner(self.sequencer)
            self._slots.run(load, operator)
        except (StationBusy, Refused) as exc:  # nothing recorded: the station's refusal, not a verdict
            self.state.unit_refused(str(exc))
        except Exception as exc:  # the screen must say it, not die with the worker
            self.state.unit_refused(f"the station could not run the load: {exc}")
        finally:
            self.state.load_finished()
            self.standing()

    def _run(self, serial: str, part: str, operator: str) -> None:
        try:
            self.sequencer.run_unit(serial, part, operator)
        except (StationBusy, Refused) as exc:  # nothing recorded: the station's refusal, not a verdict
            self.state.unit_refused(str(exc))
        except UnitAborted as exc:
            self.state.unit_refused(f"{exc.reason}: no unit under test")
        except Exception as exc:  # the screen must say it, not die with the worker
            self.state.unit_refused(f"the station could not run the unit: {exc}")
        finally:
            self.standing()

    def _wait_for_wind_down(self) -> None:
        """A worker whose verdicts are all shown is only winding down: let it end before judging busy."""
        if self._thread is not None and self._thread.is_alive() and not self.state.testing():
            self._thread.join(WIND_DOWN_S)

    def busy(self) -> bool:
        """Is a unit (or a load of slots) under test?"""
        return self._thread is not None and self._thread.is_alive()

    def abort(self, reason: str = "aborted by the operator") -> bool:
        """Ask the unit under test to stop; False when none is."""
        if not self.busy():
            return False
        self.sequencer.abort.note(reason)  # the unit runs on its own thread; a slot runner passes it on
        return True

    def wait(self, timeout: float | None = None) -> None:
        if self._thread is not None:
            self._thread.join(timeout)

    def standing(self) -> None:
        """The station's standing state: field reference and results store."""
        field: dict[str, Any] = {"source": self.sequencer.station.field_source.type}
        describe = getattr(self.sequencer.field_source, "describe", None)
        if callable(describe):
            field.update(describe())
        main = self.sequencer.station.main_results.sink
        store: dict[str, Any] = {"where": getattr(self.sequencer.sink, "where", main)}
        pending = getattr(self.sequencer.sink, "pending", None)
        if callable(pending):
            try:
                store["queued"] = pending()
            except Exception as exc:  # a store that cannot say is shown as such
                store["error"] = str(exc)
        self.state.update(field=field, store=store)
        self.shift.refresh()

    def close(self) -> None:
        self.shift.close()
        self.abort()
        self.wait(30)
        self.sequencer.close()
