"""The shape of the code (issue 44): what a newcomer meets and what the layering guards hold.

Printed: lines of Python per root, the modules at core/'s top, the import cycles among magline's
modules (strongly connected components of the module import graph, imports inside functions
included; at run time, and counting the imports only type hints make), core → plugins / sim
imports, plugin → other plugin imports, and which magline modules the built-in plugins import
besides their own package and the public face.

    python benchmarks/structure.py
"""

from __future__ import annotations

import ast
import collections
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
ROOTS = {"core": "magline.core", "plugins": "magline.plugins", "sim": "magline.sim", "testing": "magline.testing",
         "plugin": "magline.plugin", "stations": "magline.stations"}


def modules() -> dict[str, Path]:
    """Installed module name → file, for every Python file under the roots."""
    found = {}
    for folder, installed in ROOTS.items():
        for path in sorted((REPO / folder).rglob("*.py")) if (REPO / folder).is_dir() else []:
            parts = path.relative_to(REPO / folder).with_suffix("").parts
            if parts[-1] == "__init__":
                parts = parts[:-1]
            found[".".join((installed, *parts))] = path
    return found


def imports(path: Path, name: str, known: set[str], typing_too: bool = True) -> set[str]:
    """The magline modules ``path`` imports (``from a import b`` counts ``a.b`` where that is a module);
    ``typing_too=False`` leaves out what only type hints import (``if TYPE_CHECKING:`` blocks)."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    hints = {id(n) for block in ast.walk(tree) if isinstance(block, ast.If) and not typing_too
             and getattr(block.test, "id", getattr(block.test, "attr", "")) == "TYPE_CHECKING"
             for stmt in block.body for n in ast.walk(stmt)}
    out: set[str] = set()
    for node in ast.walk(tree):
        if id(node) in hints:
            continue
        targets: list[str] = []
        if isinstance(node, ast.Import):
            targets = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                anchor = package.split(".")
                anchor = anchor[: len(anchor) - node.level + 1]
                base = ".".join(anchor + ([base] if base else []))
            targets = [f"{base}.{a.name}" if f"{base}.{a.name}" in known else base for a in node.names]
        for target in targets:
            while target and target not in known:
                target = target.rpartition(".")[0]
            if target and target != name:
                out.add(target)
    return out


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components with more than one module (Tarjan, iterative)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on: set[str] = set()
    out: list[list[str]] = []
    counter = 0
    for root in graph:
        if root in index:
            continue
        work = [(root, iter(sorted(graph[root])))]
        index[root] = low[root] = counter
        counter += 1
        stack.append(root)
        on.add(root)
        while work:
            node, children = work[-1]
            advanced = False
            for child in children:
                if child not in index:
                    index[child] = low[child] = counter
                    counter += 1
                    stack.append(child)
                    on.add(child)
                    work.append((child, iter(sorted(graph.get(child, ())))))
                    advanced = True
                    break
                if child in on:
                    low[node] = min(low[node], index[child])
            if advanced:
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[node])
            if low[node] == index[node]:
                component = []
                while True:
                    top = stack.pop()
                    on.discard(top)
                    component.append(top)
                    if top == node:
                        break
                if len(component) > 1:
                    out.append(sorted(component))
    return out


def plugin_of(name: str) -> str | None:
    parts = name.split(".")
    return parts[2] if len(parts) > 2 and parts[1] == "plugins" else None


def main() -> None:
    found = modules()
    known = set(found)
    graph = {name: imports(path, name, known) for name, path in found.items()}
    print("lines of Python per root:")
    for folder in [*ROOTS, "tests", "benchmarks"]:
        files = list((REPO / folder).rglob("*.py")) if (REPO / folder).is_dir() else []
        print(f"   {folder + '/':<12} {sum(len(f.read_text(encoding='utf-8').splitlines()) for f in files):>6} lines, "
              f"{len(files)} files")
    top = sorted(p.stem for p in (REPO / "core").glob("*.py") if p.stem != "__init__")
    print(f"core/'s top: {len(top)} modules ({', '.join(top)}); rooms: "
          f"{', '.join(sorted(p.name for p in (REPO / 'core').iterdir() if (p / '__init__.py').exists()))}")
    runtime = {name: imports(path, name, known, typing_too=False) for name, path in found.items()}
    for label, among in (("import cycles at run time", runtime), ("import cycles counting type hints", graph)):
        found_cycles = cycles(among)
        print(f"{label}: {len(found_cycles)}")
        for component in found_cycles:
            print(f"   {len(component)} modules: {', '.join(component[:6])}{' …' if len(component) > 6 else ''}")
    core_out = sorted((a, b) for a, bs in graph.items() if a.startswith("magline.core") for b in bs
                      if b.startswith(("magline.plugins", "magline.sim")))
    print(f"core → plugins/sim imports: {len(core_out)}")
    for a, b in core_out:
        print(f"   {a} → {b}")
    across = sorted((a, b) for a, bs in graph.items() for b in bs
                    if plugin_of(a) and plugin_of(b) and plugin_of(a) != plugin_of(b))
    print(f"plugin → other plugin imports: {len(across)}")
    for a, b in across:
        print(f"   {a} → {b}")
    used = collections.Counter(b for a, bs in graph.items() if plugin_of(a) for b in bs
                               if not plugin_of(b) and not b.startswith("magline.plugin"))
    print(f"magline modules the built-in plugins import besides their own and the public face: {len(used)}")
    for name, count in sorted(used.items()):
        print(f"   {name} ({count})")


if __name__ == "__main__":
    main()
