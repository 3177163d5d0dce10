"""Open a station's results stores: each ``results`` entry through its registered factory, its
``options`` validated against the model the plugin registered, every record written to all.

Why a fan-out: a line may keep its SQLite store and also feed a plant system (a JSON-lines file,
a message queue) without choosing one.  The first store is the station's own: run ids shown to
the operator, history, statistics and reports come from it.  A record that any store could not
take is said with that store's name (the unit is then an ERROR, as for one store).
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

from magline.core.faults import StationFault
from magline.core.plugins import Plugins

if TYPE_CHECKING:
    from magline.core.record import AttemptRecord, RunRecord
    from magline.core.station.schema import Results, Station


def open_results(station: Station, station_dir: Path, plugins: Plugins, main_only: bool = False) -> Any:
    """The station's results stores as one sink (just the first with ``main_only``: reading commands)."""
    entries = station.results[:1] if main_only else station.results
    opened: list[tuple[str, Any]] = []
    try:
        for index, entry in enumerate(entries):
            opened.append((entry.sink, open_one(station, station_dir, plugins, entry, index)))
    except BaseException:
        for _, sink in opened:
            close_sink(sink)
        raise
    return opened[0][1] if len(opened) == 1 else ResultSinks(opened)


def open_one(station: Station, station_dir: Path, plugins: Plugins, entry: Results, index: int = 0) -> Any:
    factory = plugins.result_sinks.get(entry.sink)
    if factory is None:
        raise StationFault(f"no results sink named {entry.sink!r} is loaded "
                           f"(loaded: {', '.join(sorted(plugins.result_sinks))})")
    options = plugins.options("result sink", entry.sink, entry.options, f"results[{index}].options", station_dir)
    return factory(station, Path(station_dir), entry, options)


def close_sink(sink: Any) -> None:
    """``close()`` is in the contract; a sink written before it may lack it."""
    closer = getattr(sink, "close", None)
    if callable(closer):
        closer()


# The optional capabilities' members (core/results/contract.py) a fan-out answers for its first store.
CAPABILITY_MEMBERS = ("series", "record_engine", "engine", "pending", "forward", "claim_slot", "touch_slot",
                      "release_slot", "slots_held")


class ResultSinks:
    """Several stores behind the one-sink interface; each keeps its own run id for the record.

    The first store's optional capabilities are the fan-out's: each instance's class carries exactly
    the members its first store's class has, so ``isinstance(sinks, KeepsSeries)`` answers as for that
    store (a ``__getattr__`` alone is invisible to a Protocol check that looks at the class, as
    Python 3.12's does)."""

    def __new__(cls, sinks: list[tuple[str, Any]]) -> ResultSinks:
        main_type = type(sinks[0][1])
        members = {name: property(lambda self, name=name: getattr(self.main, name))
                   for name in CAPABILITY_MEMBERS if hasattr(main_type, name)}
        return object.__new__(type(cls.__name__, (cls,), members) if members else cls)

    def __init__(self, sinks: list[tuple[str, Any]]) -> None:
        self.sinks = sinks
        self.main = sinks[0][1]
        self._ids: dict[int, dict[int, int | None]] = {}  # id(record) → store index → its run id

    def __getattr__(self, name: str) -> Any:  # history, where, server, last_error …
        return getattr(self.main, name)

    def _each(self, method: str, record: RunRecord, *args: Any) -> None:
        ids = self._ids.setdefault(id(record), {})
        main_id = ids.get(0, record.run_id)
        try:
            for index, (name, sink) in enumerate(self.sinks):
                record.run_id = main_id if index == 0 else ids.get(index)
                try:
                    getattr(sink, method)(record, *args)
                except StationFault:
                    raise
                except Exception as exc:  # a plugin store's own error, said with its name
                    raise StationFault(f"results store {name!r}: {method} failed: {exc}") from exc
                ids[index] = record.run_id
                if index == 0:
                    main_id = record.run_id
        finally:
            record.run_id = main_id

    def begin(self, record: RunRecord) -> None:
        self._each("begin", record)

    def save_attempt(self, record: RunRecord, attempt: AttemptRecord) -> None:
        self._each("save_attempt", record, attempt)

    def finish(self, record: RunRecord) -> None:
        try:
            self._each("finish", record)
        finally:
            self._ids.pop(id(record), None)

    def location(self, record: RunRecord) -> str:
        where = getattr(self.main, "location", None)
        text = where(record) if callable(where) else self.sinks[0][0]
        return f"{text}; also in {', '.join(name for name, _ in self.sinks[1:])}"

    def close(self) -> None:
        for _, sink in self.sinks:
            close_sink(sink)
