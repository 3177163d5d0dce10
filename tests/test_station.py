"""Station files: every problem named with file, line and key; nothing runs on a bad file."""

from __future__ import annotations

import pytest
from conftest import REPO

from magline.core.cli import main
from magline.core.station import StationError, load_station, load_station_text

GOOD = """\
station:
  id: s1
  line: L1
  location: {latitude_deg: 47.0, longitude_deg: 8.0}
products:
  P1:
    backend: mock
    limits:
      coverage: {ge: 0.6}
field_source: {type: fixed, options: {field_ut: 48.0}}
limits:
  coverage: {ge: 0.5}
  residual_rms_ut: {le: 1.0, marginal: 0.1}
"""


def problems(text: str) -> list[str]:
    with pytest.raises(StationError) as info:
        load_station_text(text, "line7.yaml")
    return info.value.problems


def test_good_file_loads_and_product_overrides_line_limits():
    station = load_station_text(GOOD, "ok.yaml")
    limits = station.effective_limits("P1")
    assert limits["coverage"].low == 0.6 and limits["residual_rms_ut"].high == 1.0
    other = load_station_text(GOOD.replace("coverage: {ge: 0.6}", "coverage: {ge: 0.7}"), "ok.yaml")
    assert station.limit_hash("P1") != other.limit_hash("P1")
    assert len(station.limit_hash("P1")) == 16


def test_unknown_key_names_file_line_and_key():
    out = problems(GOOD.replace("  line: L1\n", "  line: L1\n  colour: red\n"))
    assert out == ["line7.yaml:4: station.colour: unknown key"]


def test_wrong_type():
    out = problems(GOOD.replace("latitude_deg: 47.0", "latitude_deg: north"))
    assert len(out) == 1 and out[0].startswith("line7.yaml:4: station.location.latitude_deg:")
    assert "north" in out[0]


def test_missing_key_points_at_its_parent():
    out = problems(GOOD.replace("    backend: mock\n", ""))
    assert out == ["line7.yaml:6: products.P1.backend: required key is missing"]


def test_unknown_measurement_in_limits():
    out = problems(GOOD.replace("residual_rms_ut: {le", "residual_rms: {le"))
    assert len(out) == 1 and out[0].startswith("line7.yaml:13: limits.residual_rms: ")
    assert "unknown measurement" in out[0]


def test_several_problems_reported_together_and_duplicates_caught():
    out = problems(GOOD.replace("  line: L1\n", "  line: L1\n  line: L2\n  extra: 1\n"))
    assert any("duplicate key" in p and ":4:" in p for p in out)
    assert any("station.extra: unknown key" in p for p in out)


def test_yaml_syntax_error_and_unsafe_tags():
    assert problems("station: [unclosed\n")[0].startswith("line7.yaml:")
    out = problems("station: !!python/object/apply:os.system ['echo hi']\n")
    assert "YAML" in out[0]


def test_unknown_backend_named_by_check(tmp_path, capsys):
    path = tmp_path / "bad.yaml"
    path.write_text(GOOD.replace("backend: mock", "backend: px9"), encoding="utf-8")
    assert main(["check", str(path)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith(f"{path}:7: products.P1.backend: unknown DUT backend 'px9'")


def test_check_good_file(tmp_path, capsys):
    path = tmp_path / "ok.yaml"
    path.write_text(GOOD, encoding="utf-8")
    assert main(["check", str(path)]) == 0
    assert "OK" in capsys.readouterr().out


def test_shipped_station_files_are_valid():
    from pathlib import Path
    for path in (Path(__file__).resolve().parents[1] / "stations").glob("*.yaml"):
        assert load_station(path).products


def test_run_with_bad_station_exits_2_and_runs_nothing(tmp_path, capsys):
    path = tmp_path / "bad.yaml"
    path.write_text(GOOD.replace("  line: L1\n", ""), encoding="utf-8")
    assert main(["run", str(path), "--serial", "X1"]) == 2
    assert "station.line: required key is missing" in capsys.readouterr().err
    assert not (tmp_path / "magline-results.sqlite").exists()


def test_check_validates_backend_and_power_options_with_lines(make_station, capsys):
    """Options declared by the plugins are checked by ``magline check``, before any unit is connected."""
    from magline.core.cli import main

    path = make_station({"products": {"MOCK-100": {
        "options": {"noise_ut": -1.0, "colour": "red"},
        "power": {"method": "scpi-supply", "options": {"voltage_v": 5.0}}}}})
    assert main(["check", str(path)]) == 2
    err = capsys.readouterr().err
    text = path.read_text(encoding="utf-8").splitlines()
    noise_line = next(i for i, line in enumerate(text, 1) if "noise_ut" in line)
    assert f"{path}:{noise_line}: products.MOCK-100.options.noise_ut: Input should be greater than or equal to 0" in err
    assert "products.MOCK-100.options.colour: unknown key" in err  # the core's own words
    assert "products.MOCK-100.power.options.resource: required key is missing" in err


@pytest.mark.parametrize(("changes", "key", "said"), [
    ({"results": {"sink": "sqlite", "options": {"path": "other.sqlite"}}}, "results.options.path",
     "result sink 'sqlite' takes no options"),
    ({"results": {"sink": "sql", "url_env": "DB_URL", "options": {"url": "postgresql://x"}}}, "results.options.url",
     "result sink 'sql' takes no options"),
    ({"products": {"MOCK-100": {"power": {"method": "link-reboot", "options": {"delay_s": 2}}}}},
     "products.MOCK-100.power.options.delay_s", "power control 'link-reboot' takes no options"),
    ({"motion": {"type": "operator", "options": {"speed": 2}}}, "motion.options.speed",
     "motion 'operator' takes no options"),
])
def test_an_option_under_a_name_that_takes_none_is_a_check_error_not_ignored(make_station, capsys, changes, key,
                                                                             said):
    """A store's ``path`` written under its ``options`` would be ignored, the records kept elsewhere than the
    engineer wrote: ``magline check`` names it with its line, and ``magline run`` tests no unit."""
    from magline.core.cli import main

    path = make_station(changes)
    line = [n for n, text in enumerate(path.read_text(encoding="utf-8").splitlines(), 1)  # the options' own:
            if text.strip().startswith(key.rsplit(".", 1)[-1] + ":")][-1]                  # written after the rest
    for argv in (["check", str(path)], ["run", str(path), "--serial", "X1"]):
        assert main(argv) == 2
        assert f"{path}:{line}: {key}: unknown key: {said}" in capsys.readouterr().err
    assert not list(path.parent.glob("*.sqlite"))


def test_a_station_altitude_outside_the_field_model_is_a_check_error(make_station, capsys):
    from magline.core.cli import main

    path = make_station({"station": {"location": {"altitude_m": -4080.0}}})  # 408 m, a slip of sign and unit
    assert main(["check", str(path)]) == 2
    assert "station.location.altitude_m: Input should be greater than or equal to -1000" in capsys.readouterr().err


def test_fit_settings_are_checked_with_their_line():
    out = problems(GOOD + "fit:\n  gain_sigma: 0\n  max_direction_sigma_deg: 0.5\n")
    assert len(out) == 1 and out[0].startswith("line7.yaml:15: fit.gain_sigma:")
    station = load_station_text(GOOD + "fit:\n  gain_sigma: 0.01\n", "ok.yaml")
    assert station.fit.gain_sigma == 0.01 and station.fit.max_direction_sigma_deg == 1.0


def test_an_empty_or_impossible_acceptance_window_is_a_check_error(make_station):
    from magline.testing import check_station

    path = make_station({"limits": {"hard_iron_sigma_ut": {"le": -0.5, "ge": 1}, "coverage": {"ge": 1.5},
                                    "mag2.rejected_fraction": {"le": -0.1}}})
    found = {p.key: p.message for p in check_station(path)}
    assert "empty acceptance window" in found["limits.hard_iron_sigma_ut"]
    assert "no value can lie in [1.5, —]: coverage is always within [0, 1]" in found["limits.coverage"]
    assert "rejected_fraction is always within [0, 1]" in found["limits.mag2.rejected_fraction"]


def test_every_mistake_is_reported_in_one_pass_each_at_its_own_line(make_station):
    from magline.testing import check_station

    path = make_station({"default_part": "MOCK-10", "acquisition": {"samples": 5}, "limits": {"coverage": {"ge": 2}}})
    problems = check_station(path)
    keys = [p.key for p in problems]
    assert "default_part" in keys and "acquisition.samples" in keys and "limits.coverage" in keys
    default = next(p for p in problems if p.key == "default_part")
    assert "did you mean 'MOCK-100'?" in default.message
    text = path.read_text(encoding="utf-8").splitlines()
    assert text[default.line - 1].startswith("default_part:")


GOOD_CONNECTIONS = {
    "px4": ["udpout://127.0.0.1:14550", "udpin://0.0.0.0:14540", "tcpout://10.0.0.7:5760", "udp://:14540",
            "serial:/dev/serial/by-path/pci-0000:00:14.0-usb-0:1.1:1.0:115200", "serial:/dev/ttyACM0"],
    "ardupilot": ["tcp:127.0.0.1:5760", "udpin:0.0.0.0:14550", "udpout:10.0.0.7:14550", "serial:/dev/ttyACM0:57600"],
    "inav": ["tcp:127.0.0.1:5760", "serial:/dev/serial/by-id/usb-INAV_Board-if00"],
}
BAD_CONNECTIONS = [
    ("px4", "udpout://127.0.0.1:99999", "99999 is not a port (1 to 65535)"),
    ("px4", "udpout://127.0.0.1:0", "0 is not a port (1 to 65535)"),
    ("px4", "udpout:127.0.0.1:14550", "'udpout:127.0.0.1:14550' is no connection this backend opens: expected "
                                      "udpin://HOST:PORT, udpout://HOST:PORT"),
    ("px4", "udpin://:14540", "'udpin://:14540' names no HOST:PORT"),
    ("ardupilot", "tcp://127.0.0.1:5760", "is no connection this backend opens: expected tcp:HOST:PORT"),
    ("ardupilot", "tcp:127.0.0.1", "names no HOST:PORT"),
    ("inav", "udpin:0.0.0.0:5760", "expected tcp:HOST:PORT or serial:DEVICE[:BAUD]"),
    ("inav", "serial:ttyACM0:115200", "expected serial:DEVICE:BAUD with an absolute DEVICE path"),
]


def _connection_problems(make_station, backend: str, connection: str, name: str = "station.yaml") -> list:
    from magline.testing import check_station

    path = make_station({"products": {"MOCK-100": {"backend": backend, "connection": connection}}}, name=name)
    return [(p.line, p.message) for p in check_station(path) if p.key == "products.MOCK-100.connection"], path


@pytest.mark.parametrize(("backend", "connection"), [(b, c) for b, cs in GOOD_CONNECTIONS.items() for c in cs])
def test_a_connection_the_backend_opens_is_no_problem(make_station, backend, connection):
    assert _connection_problems(make_station, backend, connection)[0] == []


@pytest.mark.parametrize(("backend", "connection", "said"), BAD_CONNECTIONS)
def test_a_connection_no_link_can_open_is_a_check_error_with_its_line(make_station, backend, connection, said):
    """Found before, only when a unit was connected: an ERROR of every unit that no retest could cure."""
    (found,), path = _connection_problems(make_station, backend, connection)
    line, message = found
    assert said in message
    assert path.read_text(encoding="utf-8").splitlines()[line - 1].strip() == f"connection: {connection}"


def test_a_slot_s_connection_is_judged_by_its_part_s_backend(tmp_path):
    from magline.testing import check_station

    shipped = REPO / "stations" / "slots-sim.yaml"
    assert check_station(shipped) == []
    broken = tmp_path / "slots.yaml"
    broken.write_text(shipped.read_text(encoding="utf-8").replace(
        '{id: C, part: AP-QUAD-200, connection: "tcp:127.0.0.1:5760"}',
        '{id: C, part: AP-QUAD-200, connection: "udpout://127.0.0.1:5760"}'), encoding="utf-8")
    (problem,) = check_station(broken)
    assert (problem.key, problem.line) == ("slots[2].connection", 39)
    assert problem.message.startswith("'udpout://127.0.0.1:5760' is no connection this backend opens: expected tcp:")


def test_a_slot_s_own_power_control_is_checked_as_a_product_s(tmp_path):
    """A slot may have its own power control: its method and options were taken unread by ``magline check``."""
    from magline.testing import check_station

    shipped = REPO / "stations" / "slots-sim.yaml"
    broken = tmp_path / "slots.yaml"
    broken.write_text(shipped.read_text(encoding="utf-8").replace(
        '{id: A, part: PX4-X500-100, connection: "udpout://127.0.0.1:14550"}',
        '{id: A, part: PX4-X500-100, connection: "udpout://127.0.0.1:14550", power: {method: scpi-suply}}\n'
        '  - {id: E, part: PX4-X500-100, connection: "udpout://127.0.0.1:14552", power: {method: scpi-supply, '
        'options: {volts: 5}}}'), encoding="utf-8")
    found = [(p.line, p.key, p.message.split(";")[0]) for p in check_station(broken)]
    assert found == [(37, "slots[0].power.method", "unknown power control 'scpi-suply' (did you mean 'scpi-supply'?)"),
                     (38, "slots[1].power.options.resource", "required key is missing"),
                     (38, "slots[1].power.options.volts", "unknown key")]


def test_two_slots_on_one_vehicle_link_are_a_check_error(tmp_path):
    """A slot line copied without its connection changed: both slots would test the unit on that link (the
    second refused at run time, as its vehicle is held).  A slot without a connection has its part's."""
    from magline.testing import check_station

    shipped = (REPO / "stations" / "slots-sim.yaml").read_text(encoding="utf-8")
    copied = tmp_path / "copied.yaml"
    copied.write_text(shipped.replace('connection: "udpout://127.0.0.1:14551"', 'connection: "udpout://127.0.0.1:14550"'),
                      encoding="utf-8")
    unsaid = tmp_path / "unsaid.yaml"
    unsaid.write_text(shipped.replace(', connection: "udpout://127.0.0.1:14551"', ""), encoding="utf-8")
    said = "udpout://127.0.0.1:14550 is slot A's link too: two slots would test one unit"
    for path, key in ((copied, "slots[1].connection"), (unsaid, "slots[1]")):
        (problem,) = check_station(path)
        assert (problem.line, problem.key) == (38, key) and problem.message.startswith(said)


def test_slots_of_an_in_process_mock_share_its_connection_freely(make_station):
    """The mock's connection names no link: its slots may all write the same words."""
    from magline.testing import check_station

    path = make_station({"slots": [{"id": "A", "part": "MOCK-100"}, {"id": "B", "part": "MOCK-100"}]})
    assert check_station(path) == []



SHARED_STORES = """\
results:
  - sink: sqlite
    path: line.sqlite
  - {sink: sqlite, path: ./line.sqlite}
  - sink: sql
    url_env: PLANT_DB
  - sink: sql
    url_env: QA_DB
  - sink: sql
    url_env: PLANT_DB
    outbox: plant-outbox.sqlite
"""


def _demo_with(results: str) -> str:
    """The shipped demo station with its ``results:`` block replaced (the block starts at line 48)."""
    demo = (REPO / "stations" / "demo.yaml").read_text(encoding="utf-8")
    return demo.replace("results:\n  sink: sqlite\n  path: magline-demo-results.sqlite\n", results)


def test_two_results_stores_writing_one_file_or_one_server_are_a_check_error(tmp_path):
    """Each unit would be recorded twice in that store, and its yield and statistics count it twice: a copied
    line, or two ``sql`` stores both on the default outbox.  Said at the second store's line, naming the first."""
    from magline.testing import check_station

    path = tmp_path / "shared.yaml"
    path.write_text(_demo_with(SHARED_STORES), encoding="utf-8")
    found = [(p.line, p.key, p.message.split(" too:")[0]) for p in check_station(path)]
    assert found == [(51, "results[1].path", "./line.sqlite is results[0].path's SQLite file"),
                     (54, "results[3]", "magline-outbox.sqlite is results[2].outbox's SQLite file"),
                     (57, "results[4].url_env", "the environment variable PLANT_DB is results[2].url_env's server")]
    assert all("every unit would be recorded twice in it" in p.message for p in check_station(path))


def test_stores_of_their_own_pass_the_check(tmp_path):
    """Different files and servers are the usual fan-out; the same file name in another folder is another file."""
    from magline.testing import check_station

    path = tmp_path / "own.yaml"
    path.write_text(_demo_with(SHARED_STORES).replace("./line.sqlite", "copy/line.sqlite")
                    .replace("url_env: QA_DB", "url_env: QA_DB\n    outbox: qa.sqlite")
                    .replace("PLANT_DB\n    outbox: plant-outbox.sqlite", "MES_DB\n    outbox: mes.sqlite"),
                    encoding="utf-8")
    assert check_station(path) == []
