"""magline's pytest plugin (entry point ``pytest11``): fixtures for plugin authors' tests.

Inert unless used: it defines fixtures only (no hooks, no imports of magline's heavy parts until
a fixture is requested), so installing magline changes nothing in other projects' test runs.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from contextlib import ExitStack
from pathlib import Path
from typing import Any

import pytest


@pytest.fixture
def magline_station(tmp_path: Path) -> Callable[..., Path]:
    """``magline_station(changes=None, base="demo.yaml", name="station.yaml", replace=None)`` writes
    a station file into the test's tmp dir (see :func:`magline.testing.station_file`)."""
    from magline.testing.stations import station_file

    def make(changes: dict | None = None, base: str = "demo.yaml", name: str = "station.yaml",
             replace: dict | None = None) -> Path:
        return station_file(tmp_path, changes, base, name, replace)

    return make


@pytest.fixture
def magline_run() -> Callable[..., Any]:
    """``magline_run(station, serial="SN-1", extra=[your_plugin])``: one unit, its record."""
    from magline.testing.stations import run_unit

    return run_unit


@pytest.fixture
def magline_px4(tmp_path: Path) -> Iterator[Callable[..., Any]]:
    """``magline_px4(**options)``: a simulated PX4 on a free UDP port, stopped after the test;
    ``.connection`` for the station file, ``.sim`` for faults and storage."""
    from magline.testing.sims import px4_sim

    with ExitStack() as stack:
        count = iter(range(1000))
        yield lambda **options: stack.enter_context(px4_sim(tmp_path / f"px4-{next(count)}", **options))


@pytest.fixture
def magline_ardupilot(tmp_path: Path) -> Iterator[Callable[..., Any]]:
    """``magline_ardupilot(**options)``: a simulated ArduPilot on a free TCP port, stopped after the test."""
    from magline.testing.sims import ardupilot_sim

    with ExitStack() as stack:
        count = iter(range(1000))
        yield lambda **options: stack.enter_context(ardupilot_sim(tmp_path / f"ap-{next(count)}", **options))


@pytest.fixture
def magline_inav(tmp_path: Path) -> Iterator[Callable[..., Any]]:
    """``magline_inav(**options)``: a simulated INAV (MSP) on a free TCP port, stopped after the test."""
    from magline.testing.sims import inav_sim

    with ExitStack() as stack:
        count = iter(range(1000))
        yield lambda **options: stack.enter_context(inav_sim(tmp_path / f"inav-{next(count)}", **options))


@pytest.fixture
def magline_mock_dut(tmp_path: Path) -> Iterator[Callable[..., Any]]:
    """``magline_mock_dut(**options)``: the in-process mock DUT (``MockOptions``; its storage in the
    test's tmp dir unless given), closed after the test."""
    from magline.plugins.mock.dut import MockDut
    from magline.plugins.mock.options import MockOptions

    made: list[Any] = []

    def make(**options: Any) -> Any:
        options.setdefault("storage", str(tmp_path / f"mock-storage-{len(made)}.json"))
        made.append(MockDut(MockOptions(**options)))
        return made[-1]

    yield make
    for dut in made:
        dut.close()


@pytest.fixture
def magline_results() -> Callable[..., Any]:
    """``magline_results(station_path)``: the station's own results store, read through magline's
    reading API (``.history(serial)``, ``.run(run_id)`` the whole record, ``.attempts(serial)``
    with the raw readings of each attempt)."""
    from magline.testing.stations import StoredResults

    return StoredResults
