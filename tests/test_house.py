"""A root per role (issue 44, first step): the simulators live in ``sim/`` (installed ``magline.sim``)
with the synthetic truth they share (``sim/truth``), ``magline sim`` comes through its own entry point,
core imports no simulator and no plugin, and the simulators import no plugin."""

from __future__ import annotations

import ast
import inspect
from importlib.metadata import entry_points

import pytest
from conftest import REPO


def imports_of(folder: str) -> dict[str, set[str]]:
    """Every ``magline.…`` module each file under ``folder`` imports (at any depth of the file)."""
    found: dict[str, set[str]] = {}
    for path in (REPO / folder).rglob("*.py"):
        names: set[str] = set()
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.ImportFrom) and node.module and node.module.startswith("magline."):
                names.add(node.module)
            elif isinstance(node, ast.Import):
                names |= {a.name for a in node.names if a.name.startswith("magline.")}
        found[str(path.relative_to(REPO))] = names
    return found


def test_core_imports_no_simulator_and_no_plugin():
    offending = {f: sorted(n for n in names if n.startswith(("magline.sim", "magline.plugins")))
                 for f, names in imports_of("core").items()}
    assert {f: n for f, n in offending.items() if n} == {}


def test_the_simulators_import_no_plugin():
    offending = {f: sorted(n for n in names if n.startswith("magline.plugins"))
                 for f, names in imports_of("sim").items()}
    assert {f: n for f, n in offending.items() if n} == {}


def test_magline_sim_comes_through_its_own_entry_point_and_the_mock_plugin_adds_no_command():
    group = {ep.name: ep.value for ep in entry_points(group="magline")}
    assert group["sim"] == "magline.sim.commands"
    import magline.plugins.mock.plugin as mock

    assert not hasattr(mock, "magline_add_commands")
    assert not (REPO / "plugins" / "mock" / "sim").exists()


def test_each_simulator_lists_its_own_options_and_every_fault(capsys):
    import pytest

    from magline.core.cli import main
    from magline.sim.faults import SimFaults

    def helped(*args: str) -> str:
        with pytest.raises(SystemExit):
            main(["sim", *args, "--help"])
        return " ".join(capsys.readouterr().out.split())  # argparse wraps: compare as one line

    px4, ardupilot, coil = helped("px4"), helped("ardupilot"), helped("coil")
    from dataclasses import fields

    # each lists every fault its board has (mag_mounting, mag_warmup …), and none of another board's only
    assert all(f.name in px4 for f in SimFaults.for_board("px4"))
    assert all(f.name in ardupilot for f in SimFaults.for_board("ardupilot"))
    assert {f.name for f in fields(SimFaults)} == {f.name for b in SimFaults.BOARDS for f in SimFaults.for_board(b)}
    assert "--firmware" in px4 and "--firmware" not in ardupilot
    assert "--fault" not in coil and "--firmware" not in coil and "--fluxgate" in coil and "--coil-fault" in coil
    assert "default tcp:127.0.0.1:5760" in ardupilot and "default udp:127.0.0.1:14550" in px4


def test_a_simulator_keeps_its_storage_out_of_the_folder_it_is_started_in_and_says_where_and_why_it_stopped(
        tmp_path):
    import os
    import signal
    import subprocess
    import sys
    import tempfile

    proc = subprocess.Popen([sys.executable, "-m", "magline.core.cli", "sim", "ardupilot", "--listen",
                             "tcp:127.0.0.1:0", "--boot-time", "0.2"], cwd=tmp_path, stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True, env={**os.environ, "PYTHONUNBUFFERED": "1"})
    try:
        assert proc.stdout.readline().startswith("listening on tcp:127.0.0.1:")
        said = proc.stdout.readline()
        storage = said.split("storage ", 1)[1].split(",", 1)[0]
        assert storage.startswith(tempfile.gettempdir()) and storage.endswith("eeprom.json"), said
    finally:
        proc.send_signal(signal.SIGTERM)
        rest = proc.communicate(timeout=20)[0]
    assert proc.returncode == 0 and "stopped by SIGTERM: the simulator has closed its socket" in rest
    assert list(tmp_path.iterdir()) == []  # nothing written where it was started


def test_a_station_screen_on_a_taken_port_says_so_before_announcing_anything(tmp_path, capsys, monkeypatch):
    import socket

    from magline.core.cli import main

    monkeypatch.chdir(tmp_path)
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        assert main(["station", "--port", str(port)]) == 2
    out, err = capsys.readouterr()
    assert "station screen on" not in out
    assert f"magline station: cannot listen on 127.0.0.1:{port}: Address already in use" in err


@pytest.mark.parametrize("command", ["station", "dashboard"])
@pytest.mark.parametrize(("port", "said"), [("99999", "99999 is not a TCP port (0 to 65535; 0: any free one)"),
                                            ("-1", "-1 is not a TCP port"),
                                            ("eighty", "'eighty' is not a port number")])
def test_a_port_that_is_no_port_is_refused_before_anything_is_served(capsys, monkeypatch, tmp_path, command, port,
                                                                     said):
    """A port past 65535 was bound modulo 65536 by the resolver (99999 served on 34463, announced as 99999)."""
    from magline.core.cli import main

    monkeypatch.chdir(tmp_path)  # the embedded demo's store would be opened here, were the port taken

    with pytest.raises(SystemExit) as refused:
        main([command, "--port", port])
    out, err = capsys.readouterr()
    assert refused.value.code == 2 and out == ""
    assert f"argument --port: {said}" in err


# The executive's contracts and its entry points; every other concept has a room (a folder) of its own:
# links (core/links), acquisition (core/acquisition), the sequencer, fit, mounting, results, quality …
# ``lazy``: how the packages offer their names on first use (a command's start imports only what it uses).
CORE_TOP = {"__init__", "cli", "dut", "entry", "faults", "hookspecs", "lazy", "measurements", "phases", "plugins",
            "power", "record", "serials", "text"}


def test_cores_top_holds_only_the_modules_decided():
    assert {p.stem for p in (REPO / "core").glob("*.py")} == CORE_TOP


@pytest.mark.parametrize("flavour", ["inav", "ardupilot", "gimbal"])
def test_a_simulator_on_a_taken_address_names_the_address_and_what_was_to_listen_there(tmp_path, capsys, flavour):
    """INAV's and ArduPilot's simulators both default to tcp:127.0.0.1:5760: the second one started says
    where it could not listen, not only the system's "Address already in use"."""
    import socket

    from magline.core.cli import main

    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        assert main(["sim", flavour, "--listen", f"tcp:127.0.0.1:{port}", "--workdir", str(tmp_path)]
                    if flavour != "gimbal" else ["sim", flavour, "--listen", f"tcp:127.0.0.1:{port}"]) == 2
    err = capsys.readouterr().err
    assert f"magline sim: cannot listen on tcp:127.0.0.1:{port} (the " in err
    assert "Address already in use — another program (another simulator?) listens there" in err


def test_plugins_import_only_the_public_face_and_their_own_package():
    """Issue 44: a plugin uses ``magline.plugin`` and its own files, never core's internals nor another
    plugin; the mock DUT is an in-process simulator and also uses the simulators' truth (``magline.sim``)."""
    offending = {}
    for f, names in imports_of("plugins").items():
        own = "magline.plugins." + f.split("/")[1]
        allowed = ("magline.plugin", own, *(("magline.sim",) if own == "magline.plugins.mock" else ()))
        wrong = sorted(n for n in names if not any(n == a or n.startswith(a + ".") for a in allowed))
        if wrong:
            offending[f] = wrong
    assert offending == {}


def test_the_example_plugin_and_the_reference_use_only_the_public_face():
    """The example's simulator is test support: it may use the testing kit's face, ``magline.testing``."""
    example = REPO / "examples" / "acme-magline" / "src"
    for path in example.rglob("*.py"):
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.ImportFrom) and node.module and node.module.startswith("magline"):
                assert node.module in ("magline.plugin", "magline.testing"), \
                    f"{path.relative_to(REPO)} imports {node.module}"
    reference = (REPO / "docs" / "plugins.md").read_text(encoding="utf-8")
    assert "from magline.plugin import hookimpl" in reference and "magline.core.plugins" not in reference


def test_the_public_face_lists_exactly_what_it_offers():
    import magline.plugin as face

    public = set(dir(face))
    assert set(face.__all__) == public
    assert len(face.__all__) == len(set(face.__all__))
    # each name comes from its home on first use (a command's start imports only what it uses) …
    assert all(getattr(face, name) is not None for name in face.__all__)
    # … and a name the face does not offer is an AttributeError, as from any module
    with pytest.raises(AttributeError, match="no attribute 'fit_calibration'"):
        face.fit_calibration  # noqa: B018
    # a plugin's every contract is there: a factory returns one of these
    assert {"hookimpl", "DutBackend", "FieldSource", "Motion", "PowerControl", "ResultSink"} <= public


def test_core_asks_a_backend_for_a_capability_by_its_protocol_not_by_a_name():
    """Issue 44: optional DUT methods are Protocols in ``core/dut.py``; no ``getattr(dut, "…")`` probes."""
    import re

    probe = re.compile(r"\b(getattr|hasattr)\((run\.)?dut\b")
    found = [f"{p.relative_to(REPO)}:{n}" for p in (REPO / "core").rglob("*.py")
             for n, line in enumerate(p.read_text(encoding="utf-8").splitlines(), 1) if probe.search(line)]
    assert found == []


def test_each_built_in_backend_has_the_capabilities_its_firmware_offers():
    """What each backend can do, as the core sees it: a method renamed in a backend drops the capability
    silently (the core does without it), so the list is held here."""
    from magline import plugin as face
    from magline.plugins.ardupilot.dut import ArduPilotDut
    from magline.plugins.mock.dut import MockDut
    from magline.plugins.px4.dut import Px4Dut

    capabilities = [face.CalibratesSeveral, face.ReportsSensorsPresent, face.WritesOrientation, face.WritesRotation,
                    face.ReportsUptime, face.ReadsCalibratedField, face.ReadsCalibratedFields,
                    face.ReadsRawAndCalibrated]

    def has(cls) -> set[str]:
        return {c.__name__ for c in capabilities if issubclass(cls, c)} | (
            {"HasBootTimeout"} if isinstance(getattr(cls, "boot_timeout_s", None), property) else set())

    several = {"CalibratesSeveral", "ReportsSensorsPresent", "WritesOrientation", "ReportsUptime",
               "ReadsCalibratedField", "HasBootTimeout"}
    assert has(Px4Dut) == several | {"WritesRotation", "ReadsRawAndCalibrated"}
    assert has(ArduPilotDut) == several | {"ReadsCalibratedFields"}
    assert has(MockDut) == {"ReportsUptime", "ReadsCalibratedField"}


def test_the_sequencer_imports_no_output_room():
    """Issue 44: reports, the process review, the results stores and what the operator sees listen
    to the run's hooks (``magline_unit_judged``, ``magline_record_unit``, ``magline_unit_finished`` …);
    the sequencer runs the procedure, opens the station's stores from the registry for the run to
    carry (``run.results``) and writes nothing into them itself."""
    import re

    outputs = ("magline.core.reports", "magline.core.quality", "magline.core.operator_ui")
    offending = {f: sorted(n for n in names if n.startswith(outputs))
                 for f, names in imports_of("core/sequencer").items()}
    assert {f: n for f, n in offending.items() if n} == {}
    group = {ep.name: ep.value for ep in entry_points(group="magline")}
    assert group["process_review"] == "magline.core.quality.in_run"
    assert group["unit_reports"] == "magline.core.reports.unit_report"
    assert group["results_store"] == "magline.core.results.recorder"
    writes = re.compile(r"\.(begin|save_attempt|finish)\(")
    found = [f"{p.name}:{n}" for p in (REPO / "core" / "sequencer").glob("*.py")
             for n, line in enumerate(p.read_text(encoding="utf-8").splitlines(), 1) if writes.search(line)]
    assert found == []


def test_the_readme_is_a_front_page_and_every_page_it_points_to_is_in_the_repository():
    """Issue 44: the README says what magline is, gives the two commands and the commands table, and
    points to docs/ for the operator, the quality engineer, the station file, the firmware facts and
    the plugin author; the facts the code relies on are in docs/, never in a folder outside it."""
    import re

    readme = (REPO / "README.md").read_text(encoding="utf-8")
    lines = readme.splitlines()
    first = next(n for n, line in enumerate(lines) if line.startswith("python3 -m venv"))
    assert first <= 6 and lines[first].startswith("python3 -m venv .venv && .venv/bin/pip install -q -e . && ")
    assert "pip install -q -e '.[test]'" in lines[first + 1]  # the two commands, what magline is above them
    assert "calibrates drone magnetometers" in " ".join(lines[:first])
    assert "## Try a real station" in readme and "magline run stations/px4-sim.yaml" in readme
    assert len(readme.splitlines()) < 100
    pages = re.findall(r"\]\((docs/[\w-]+\.md)\)", readme)
    assert {"docs/operator.md", "docs/quality.md", "docs/station-file.md", "docs/firmware.md",
            "docs/writing-plugins.md", "docs/plugins.md"} <= set(pages)
    assert all((REPO / p).is_file() for p in pages)
    outside = [f"{p.relative_to(REPO)}:{n}" for root in ("core", "plugins", "sim", "testing", "plugin")
               for p in (REPO / root).rglob("*.py")
               for n, line in enumerate(p.read_text(encoding="utf-8").splitlines(), 1)
               if "shared/reference" in line or re.search(r"reference §", line)]
    assert outside == []


def test_no_import_cycle_among_maglines_modules_at_run_time():
    """Issue 44: two modules importing each other (one of them inside a function to get away with it)
    is one concept in two rooms; ``benchmarks/structure.py`` prints the graph's figures."""
    import importlib.util

    spec = importlib.util.spec_from_file_location("structure", REPO / "benchmarks" / "structure.py")
    structure = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(structure)
    found = structure.modules()
    runtime = {name: structure.imports(path, name, set(found), typing_too=False) for name, path in found.items()}
    assert structure.cycles(runtime) == []


def test_core_asks_a_results_store_for_a_capability_by_its_protocol_and_a_fan_out_answers_as_its_first():
    """Sinks likewise (issue 44): no ``getattr(sink, "series")`` probes; several stores behind one
    answer each capability as the station's own (the first) does."""
    import re

    from magline.core.results.contract import ClaimsSlots, HoldsRecordsInSql, KeepsSeries, ReadsInSql, SaysWhere
    from magline.core.results.sinks import ResultSinks
    from magline.core.results.sqlite_store import SqliteSink
    from magline.core.sequencer.slots import Serialized

    probe = re.compile(r"""\b(getattr|hasattr)\((self\.)?(sink|store|run\.results)\b, ["']"""
                       r"""(series|engine|record_engine|location|forward|pending|claim_slot|slots_held)""")
    found = [f"{p.relative_to(REPO)}:{n}" for p in (REPO / "core").rglob("*.py")
             for n, line in enumerate(p.read_text(encoding="utf-8").splitlines(), 1) if probe.search(line)]
    assert found == []

    class Plain:  # a third-party sink with the contract only
        def begin(self, record): ...
        def save_attempt(self, record, attempt): ...
        def finish(self, record): ...
        def history(self, serial): return []
        def close(self): ...

    capabilities = (KeepsSeries, ClaimsSlots, HoldsRecordsInSql, ReadsInSql)
    plain_first = ResultSinks([("plain", Plain()), ("plain2", Plain())])
    assert not any(isinstance(plain_first, c) for c in capabilities) and isinstance(plain_first, SaysWhere)
    import tempfile
    from pathlib import Path

    with tempfile.TemporaryDirectory() as folder:
        sql = SqliteSink(Path(folder) / "r.sqlite")
        try:
            sql_first = ResultSinks([("sqlite", sql), ("plain", Plain())])
            assert all(isinstance(sql_first, c) for c in capabilities)
            assert sql_first.engine is sql.engine and sql_first.series.__self__ is sql
            # slots share a store through a lock; it answers as the store does, also to a static
            # lookup (how Python 3.12's runtime Protocols look), and its calls still take the lock
            shared = Serialized(sql)
            assert all(isinstance(shared, c) for c in capabilities) and not isinstance(Serialized(Plain()), KeepsSeries)
            assert all(inspect.getattr_static(shared, name) for name in ("series", "location", "engine", "claim_slot"))
            with shared._lock:
                assert shared.history("NONE") == []  # re-entrant for the thread holding it
            assert shared.engine is sql.engine
        finally:
            sql.close()


def test_the_readme_s_simulator_synopses_name_only_options_the_simulators_take(capsys):
    """Each ``magline sim …`` row of the README's command table: every option it shows is one the simulator's
    own help lists (the INAV row once lacked ``--speed``, which the INAV walk-through uses)."""
    import re

    from magline.core.cli import main

    rows = [line for line in (REPO / "README.md").read_text(encoding="utf-8").splitlines()
            if line.startswith("| `magline sim ")]
    assert rows
    for row in rows:
        synopsis = row.split("`")[1]
        for flavour in re.match(r"magline sim ([\w|\\]+)", synopsis).group(1).replace("\\", "").split("|"):
            with pytest.raises(SystemExit):
                main(["sim", flavour, "--help"])
            known = set(re.findall(r"--[\w-]+", capsys.readouterr().out))
            shown = set(re.findall(r"--[\w-]+", synopsis))
            assert shown <= known, (flavour, sorted(shown - known))
    assert "--speed" in next(r for r in rows if r.startswith("| `magline sim inav"))
