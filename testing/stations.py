"""Station files for tests, one unit through the phases, and ``magline check``'s problems as data."""

from __future__ import annotations

import copy
from collections.abc import Callable
from dataclasses import dataclass
from importlib.resources import files
from pathlib import Path
from typing import Any

import yaml

from magline.core.plugins import Plugins, load_plugins
from magline.core.record import RunRecord


def deep_update(base: dict, changes: dict) -> dict:
    """``base`` with ``changes`` merged in (mappings merged key by key, anything else replaced)."""
    out = copy.deepcopy(base)
    for key, value in changes.items():
        if isinstance(value, dict) and isinstance(out.get(key), dict):
            out[key] = deep_update(out[key], value)
        else:
            out[key] = value
    return out


def station_file(folder: str | Path, changes: dict | None = None, base: str = "demo.yaml",
                 name: str = "station.yaml", replace: dict | None = None) -> Path:
    """Write a station file into ``folder``: a shipped example (``base``, from ``magline.stations``, or
    a path) with ``changes`` merged in and the sections in ``replace`` replaced whole.  Relative
    paths in it (results store, mock storage) then live in ``folder``; the mock runs at full
    speed (not paced in real time) unless the changes say otherwise."""
    folder = Path(folder)
    source = Path(base) if Path(base).is_file() else files("magline.stations") / base
    cfg = yaml.safe_load(source.read_text(encoding="utf-8"))
    for product in cfg.get("products", {}).values():
        if product.get("backend") == "mock":
            product.setdefault("options", {})["realtime"] = False
    cfg.setdefault("acquisition", {})["retry_delay_s"] = 0.0
    cfg = deep_update(cfg, changes or {})
    cfg.update(replace or {})
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / name
    path.write_text(yaml.safe_dump(cfg, sort_keys=False, allow_unicode=True), encoding="utf-8")
    return path


def run_unit(station: str | Path, serial: str = "SN-1", part: str | None = None, plugins: Plugins | None = None,
             extra: list[Any] | None = None, sleep: Callable[[float], None] | None = None) -> RunRecord:
    """One unit through every phase on ``station`` (its record returned; also stored as the station
    says).  ``extra``: plugin objects to register for this run (your plugin under test, listeners);
    ``sleep``: what the retry delay does (default: nothing, so tests do not wait)."""
    from magline.core.sequencer import Sequencer

    path = Path(station)
    plugins = plugins or load_plugins(extra=extra)
    seq = Sequencer(_station(path, plugins), plugins, path.parent, sleep=sleep or (lambda s: None))
    try:
        return seq.run_unit(serial, part)
    finally:
        seq.close()


def _station(path: Path, plugins: Plugins) -> Any:
    """The station file read as the plugins know it (their own measurements may be limited in it)."""
    from magline.core.station.loader import load_station_text, read_station_text

    return load_station_text(read_station_text(path), str(path), plugins.measurements)


@dataclass(frozen=True)
class Problem:
    """One problem of a station file, as ``magline check`` prints it: ``file:line: key: message``."""

    file: str
    line: int
    key: str
    message: str

    def __str__(self) -> str:
        return f"{self.file}:{self.line}: {self.key}: {self.message}"


def check_station(path: str | Path, plugins: Plugins | None = None) -> list[Problem]:
    """Every problem ``magline check PATH`` reports (schema and plugin options), in file order;
    empty when the file is good."""
    from magline.core.station.checks import station_problems
    from magline.core.station.loader import StationError, read_station_text

    name = str(path)
    try:
        text = read_station_text(path)
    except StationError as exc:
        return [Problem(name, 0, "(file)", p.removeprefix(f"{name}: ")) for p in exc.problems]
    _, problems = station_problems(text, name, plugins or load_plugins())
    out = []
    for line in problems:
        rest = line.removeprefix(f"{name}:")
        number, _, rest = rest.partition(": ")
        key, _, message = rest.partition(": ")
        out.append(Problem(name, int(number) if number.isdigit() else 0, key, message))
    return out


class StoredResults:
    """A station's own results store, read as ``magline history`` / ``magline show`` read it."""

    def __init__(self, station: str | Path, plugins: Plugins | None = None) -> None:
        from magline.core.results.sinks import open_results

        path = Path(station)
        plugins = plugins or load_plugins()
        self.sink = open_results(_station(path, plugins), path.parent, plugins, main_only=True)

    def history(self, serial: str) -> list[dict[str, Any]]:
        return self.sink.history(serial)

    def _engine(self) -> Any:
        engine = getattr(self.sink, "record_engine", None)
        if engine is None:
            raise TypeError("this station's results store is not a SQL store: only history() is available")
        return engine

    def run(self, run_id: int | str) -> dict[str, Any] | None:
        """The whole stored record of a run (phases, attempts, measurements, parameters by stage)."""
        from magline.core.results.reading import find_run

        with self._engine().connect() as conn:
            return find_run(conn, str(run_id))

    def attempts(self, serial: str) -> list[dict[str, Any]]:
        """Every stored attempt of ``serial``; ``raw``: its readings (µT)."""
        from magline.core.results.reading import serial_attempts

        with self._engine().connect() as conn:
            return serial_attempts(conn, serial)

    def close(self) -> None:
        self.sink.close()
