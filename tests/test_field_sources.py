"""Field sources: WMM against an independent implementation, and the fluxgate reference that stops
a batch when the cell's field disagrees with the model or drifts."""

from __future__ import annotations

import datetime as dt
import warnings

import numpy as np
import pytest
import yaml
from pygeomag import GeoMag
from simstation import run_unit

from magline.core.cli import main
from magline.core.field.wmm import decimal_year, wmm_field_nt
from magline.core.record import Outcome
from magline.sim.fluxgate import FluxgateSim

PLACES = [  # (lat, lon, height above the ellipsoid in m, date)
    (47.3769, 8.5417, 408.0, dt.date(2026, 11, 22)),  # Zurich
    (-33.8688, 151.2093, 50.0, dt.date(2025, 7, 1)),  # Sydney
    (64.1466, -21.9426, 0.0, dt.date(2029, 3, 15)),  # Reykjavik
]


@pytest.mark.parametrize("lat,lon,alt_m,day", PLACES)
def test_wmm_agrees_with_pygeomag_within_1_nt(lat, lon, alt_m, day):
    ours = wmm_field_nt(lat, lon, alt_m, day, above="ellipsoid")
    theirs = GeoMag(coefficients_file="wmm/WMM_2025.COF").calculate(glat=lat, glon=lon, alt=alt_m / 1000,
                                                                   time=decimal_year(day))
    for key, value in (("x", theirs.x), ("y", theirs.y), ("z", theirs.z), ("f", theirs.f)):
        assert ours[key] == pytest.approx(value, abs=1.0), key


def test_a_date_outside_the_model_warns_and_uses_the_nearest_valid_one():
    with pytest.warns(UserWarning, match="outside the World Magnetic Model's validity"):
        late = wmm_field_nt(47.0, 8.0, 400.0, dt.date(2031, 6, 1))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        edge = wmm_field_nt(47.0, 8.0, 400.0, dt.date(2029, 12, 31))
    assert late["f"] == pytest.approx(edge["f"], abs=5.0)


def _with_field_source(path, source: dict):
    cfg = yaml.safe_load(path.read_text(encoding="utf-8"))
    cfg["field_source"] = source  # replaced whole, not merged
    path.write_text(yaml.safe_dump(cfg, sort_keys=False), encoding="utf-8")
    return path


def _wmm_station(make_station, reference: dict | None = None, date: str | dt.date = "2026-11-22"):
    options = {"date": date, **({"reference": reference} if reference else {})}
    path = make_station({"products": {"MOCK-100": {"options": {"field_ut": _zurich_ut(str(date))}}}})
    return _with_field_source(path, {"type": "wmm", "options": options})


def _zurich_ut(date: str) -> float:
    return wmm_field_nt(47.3769, 8.5417, 408.0, dt.date.fromisoformat(date))["f"] / 1000


def test_wmm_station_calibrates_to_the_model_field(make_station):
    path = _wmm_station(make_station)
    record = run_unit(path)
    assert record.verdict is Outcome.PASS, record.cause
    assert record.calibration["field_ut"] == pytest.approx(_zurich_ut("2026-11-22"), rel=1e-9)


def _reference(sim: FluxgateSim, **extra) -> dict:
    return {"resource": sim.visa_resource, "readings": 2, "every_n_units": 2, **extra}


def test_a_reference_that_disagrees_with_the_model_stops_the_batch(make_station, capsys):
    model = _zurich_ut("2026-11-22")
    with FluxgateSim("tcp:127.0.0.1:0", lambda: np.array([0.0, 0.0, model + 4.0]), noise_ut=0.0) as sim:
        path = _wmm_station(make_station, _reference(sim, tolerance_ut=1.5))
        code = main(["run", str(path), "--serial", "SN-1", "--loop"])
    assert code == 2
    err = capsys.readouterr().err
    assert "batch stopped: reference magnetometer reads" in err
    assert f"expects {model:.2f} µT (difference +4.00 µT, tolerance ±1.5 µT)" in err


def test_a_drifting_reference_stops_the_batch_and_refuses_later_units(make_station):
    from magline.core.plugins import load_plugins
    from magline.core.sequencer import Sequencer
    from magline.core.station import load_station

    model = _zurich_ut("2026-11-22")
    field = {"z": model}
    with FluxgateSim("tcp:127.0.0.1:0", lambda: np.array([0.0, 0.0, field["z"]])) as sim:
        path = _wmm_station(make_station, _reference(sim, drift_limit_ut=0.5, every_n_units=1))
        seq = Sequencer(load_station(path), load_plugins(), path.parent, sleep=lambda s: None)
        assert seq.run_unit("SN-1").verdict is Outcome.PASS
        field["z"] = model + 0.9  # a steel trolley parked next to the cell
        second = seq.run_unit("SN-2")
        third = seq.run_unit("SN-3")
        seq.close()
    assert second.verdict is Outcome.ERROR and "drifted from" in second.cause and "after 1 units" in second.cause
    assert third.verdict is Outcome.ERROR and "drifted" in third.cause  # refused until the station restarts
    assert [p.name for p in third.phases if p.outcome is not Outcome.SKIPPED] == ["identify", "connect", "record"]


@pytest.mark.parametrize(("source", "said"), [
    ({"type": "wmm", "options": {"dat": "2026-01-01"}}, "field_source.options.dat: unknown key (did you mean 'date'?)"),
    ({"type": "wmm", "options": {"date": "2026-13-01"}}, "field_source.options.date: Input should be a valid date"),
    ({"type": "fixed", "options": {"feld_ut": 48.0}}, "field_source.options.field_ut: required key is missing"),
    ({"type": "fixed", "options": {"field_ut": "48"}}, "field_source.options.field_ut: Input should be a valid "
                                                       "number (got str '48')"),
    ({"type": "fixed", "options": {"field_ut": 4800.0}}, "field_source.options.field_ut: Input should be less than "
                                                         "or equal to 1000"),
    ({"type": "fixed", "options": {"field_ut": 48.0, "inclination_deg": 95}}, "field_source.options."
                                                                              "inclination_deg: Input should be less"),
    ({"type": "fixed", "options": {"field_ut": 48.0, "reference": {"resource": "TCPIP0::x", "tolerance_ut": 0}}},
     "field_source.options.reference.tolerance_ut: Input should be greater than 0"),
])
def test_a_field_sources_wrong_option_is_told_by_check_with_its_line_and_no_unit_is_run(make_station, capsys,
                                                                                          source, said):
    """``fixed`` and ``wmm`` declare their options: a misspelt, mistyped or impossible one is named by ``magline
    check`` with the file's line, and ``magline run`` refuses the station before any unit."""
    path = _with_field_source(make_station(), source)
    lines = path.read_text(encoding="utf-8").splitlines()
    key = said.split(":")[0].split(".")[-1] if "missing" not in said else "options"  # a missing key: its mapping
    start = lines.index("field_source:")
    line = next(n for n, text in enumerate(lines[start:], start + 1) if text.strip().startswith(f"{key}:"))
    for argv in (["check", str(path)], ["run", str(path), "--serial", "X"]):
        assert main(argv) == 2
        err = capsys.readouterr().err
        assert f"{path}:{line}: {said}" in err, err
    assert not (path.parent / "magline-demo-results.sqlite").exists()


def test_a_wmm_date_written_as_a_yaml_date_or_as_text_is_the_same_day(make_station):
    """YAML reads an unquoted 2026-11-22 as a date and a quoted one as text: both are that day."""
    from magline.core.field.wmm import WmmField
    from magline.core.plugins import load_plugins
    from magline.core.station import load_station

    plugins = load_plugins()
    days = []
    for written in ("2026-11-22", dt.date(2026, 11, 22)):
        station = load_station(_wmm_station(make_station, date=written))
        options = plugins.options("field source", "wmm", station.field_source.options, "field_source.options")
        days.append(WmmField(station, options).day)
    assert days == [dt.date(2026, 11, 22)] * 2


def test_a_field_that_does_not_match_the_reference_fails_regardless_of_residual(make_station):
    path = make_station({"products": {"MOCK-100": {"options": {"field_ut": 48.0}}}})
    record = run_unit(_with_field_source(path, {"type": "fixed", "options": {"field_ut": 40.0}}))
    assert record.verdict is Outcome.FAIL
    assert "field_error_pct" in record.cause and "regardless of fit residual" in record.cause
    residual = next(m for m in record.measurements if m.name == "residual_rms_ut")
    assert residual.verdict.value == "pass"  # the fit itself is fine: only the reference says no
