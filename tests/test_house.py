"""A root per role (issue 44, first step): the simulators live in ``sim/`` (installed ``magline.sim``)
with the synthetic truth they share (``sim/truth``), ``magline sim`` comes through its own entry point,
core imports no simulator and no plugin, and the simulators import no plugin."""

from __future__ import annotations

import ast
from importlib.metadata import entry_points

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
