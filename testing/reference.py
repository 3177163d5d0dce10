"""Generate ``docs/plugins.md``, the plugin author's reference, from the code itself: every hook
specification and every contract (Protocol) with its docstrings, and the testing API.

Why generated: a reference written by hand drifts from the hooks it documents; this one cannot
(magline's CI fails when ``docs/plugins.md`` differs from what this prints).

    python -m magline.testing.reference > docs/plugins.md
"""

from __future__ import annotations

import inspect
from typing import Any

HEADER = """# Writing magline plugins — reference

Generated from the code by `python -m magline.testing.reference > docs/plugins.md`; CI fails
when this file is not current.  Start with `docs/writing-plugins.md`; this page is the
exact contract.

A plugin is a module with `@hookimpl` functions, listed under the `magline` entry-point group of
its distribution.  Everything of magline a plugin uses comes from one import, its public face:
`from magline.plugin import hookimpl, DutBackend, DutError, …` (the names are listed at the end of
this page; a plugin that imports nothing else keeps working as magline's internals move).  Registration hooks take
`register(name, factory, options=Model)`: with a pydantic `Model`, `magline check` validates the
station file's `options` for that name (file, key and line) and the factory receives the validated
model (result sinks; DUT backends and power controls receive their station entry).  Either may be named by
where it lives, `register(name, "package.module:create", options="package.module:Model")`, and is then
imported when first needed: every command registers every plugin, and what a registration imports costs
each command's start.
"""


def _signature(fn: Any) -> str:
    return f"{fn.__name__}{inspect.signature(fn)}".replace("'", "")


def _doc(obj: Any) -> str:
    return inspect.cleandoc(obj.__doc__ or "(undocumented)")


def hooks_section() -> list[str]:
    from magline.core import hookspecs

    out = ["## Hooks", "", _doc(hookspecs), "", "In the order of a station's life: registration at start-up, then a "
           "unit's phases, then what listens to them.", ""]
    specs = [fn for name, fn in inspect.getmembers(hookspecs, inspect.isfunction) if name.startswith("magline_")]
    for fn in sorted(specs, key=lambda f: f.__code__.co_firstlineno):  # hookspecs.py is written in that order
        name = fn.__name__
        opts = getattr(fn, "magline_spec", {}) or {}
        flag = " — `firstresult`: the first non-None answer wins" if opts.get("firstresult") else ""
        out += [f"### `{name}`{flag}", "", "```python", _signature(fn), "```", "", _doc(fn), ""]
    return out


def protocol_section(title: str, cls: Any) -> list[str]:
    out = [f"## {title}: `magline.plugin.{cls.__qualname__}`", "", _doc(cls), ""]
    module = inspect.getmodule(cls)
    if module is not None and module.__doc__ and cls.__doc__ is None:
        out[-2] = inspect.cleandoc(module.__doc__)
    for name, member in cls.__dict__.items():
        if name.startswith("_") or not callable(member):
            continue
        out += [f"### `{name}`", "", "```python", _signature(member), "```", "", _doc(member), ""]
    return out


def capabilities_section(contract: Any, what: str, contract_name: str,
                         required: dict[type, str] | None = None, suite: str = "") -> list[str]:
    """The optional capabilities of ``contract``'s module: a plugin's object has one by having its
    member; the core asks ``isinstance(obj, Capability)``.  ``required``: those the conformance ``suite``
    requires nevertheless, with why (said beside each)."""
    required = required or {}
    out = [f"## Optional {what} capabilities", "", f"A {what} has a capability by having its member (nothing to "
           f"declare); the core asks `isinstance(obj, Capability)` and does without it otherwise."
           + (f" Those marked *required by `{suite}`* the conformance suite asks for all the same." if required
              else ""), ""]
    caps = [obj for _, obj in inspect.getmembers(contract, inspect.isclass)
            if getattr(obj, "_is_runtime_protocol", False) and obj.__module__ == contract.__name__
            and obj.__name__ != contract_name]
    for cls in sorted(caps, key=lambda c: inspect.getsourcelines(c)[1]):
        members = [(n, m) for n, m in cls.__dict__.items() if not n.startswith("_") and callable(m)]
        fields = list(getattr(cls, "__annotations__", {}).items())
        out += [f"### `magline.plugin.{cls.__name__}`", "", "```python"]
        out += [_signature(m) for _, m in members] + [f"{n}: {t}" for n, t in fields] + ["```", "", _doc(cls), ""]
        if cls in required:
            out += [f"*Required by `{suite}`*: {required[cls]}.", ""]
    return out


def _own_summary(name: str, obj: Any) -> str:
    """The first paragraph of the object's own docstring (not one inherited from a base class, a
    dataclass's generated signature or a typing construct's)."""
    own = obj.__dict__.get("__doc__") if isinstance(obj, type) else getattr(obj, "__doc__", None)
    if not callable(obj) or not own or own.startswith(f"{name}("):
        return ""
    return inspect.cleandoc(own).split("\n\n")[0].replace("\n", " ")


TYPES = ("SampleChunk", "ImuSeries", "UnitInfo", "Magnetometer", "Numeric", "Array", "Json", "Verdict", "FitResult")
FIELD_LINE = r"^    (\w+): ([^=#]+?)(?:\s*=\s*([^#]+?))?\s*(?:#\s*(.*))?$"


def types_section() -> list[str]:
    """The public types a plugin builds or reads, each with its fields: name, type, default and the
    comment the code gives it."""
    import re

    import magline.plugin as face

    out = ["## The public types", ""]
    for name in TYPES:
        cls = getattr(face, name)
        out += [f"### `{name}`", "", _doc(cls), ""]
        rows, above = [], []
        for line in inspect.getsource(cls).splitlines()[1:]:
            if line.strip().startswith(("def ", "@")):
                break
            if line.startswith("    # "):  # a comment above a field says what it is
                above.append(line.strip()[2:])
                continue
            found = re.match(FIELD_LINE, line)
            if found and (issubclass(cls, str) or not found.group(1).isupper()):
                field_name, kind, default, comment = found.groups()
                what = comment or " ".join(above)
                rows.append(f"| `{field_name}` | `{_cell(kind.strip())}` | "
                            f"{('`' + _cell(default.strip()) + '`') if default else ''} | {_cell(what)} |")
            above = []
        if rows:
            out += ["| field | type | default | what |", "|---|---|---|---|", *rows, ""]
    return out


def _cell(text: str) -> str:
    """Text for a Markdown table cell (a ``|`` of a type union would end the cell)."""
    return text.replace("|", "\\|")


def face_section() -> list[str]:
    """Every name of the public face, with the first line of what it is."""
    import magline.plugin as face

    out = ["## The public face: `magline.plugin`", "", _doc(face), ""]
    for name in face.__all__:
        obj = getattr(face, name)
        first = _own_summary(name, obj)
        out.append(f"- `{name}`" + (f": {first}" if first else ""))
    return [*out, ""]


def testing_section() -> list[str]:
    import magline.testing as kit
    from magline.testing import plugin

    out = ["## Testing your plugin: `magline.testing`", "", _doc(kit), ""]
    for name in kit.__all__:
        obj = getattr(kit, name)
        if inspect.isfunction(obj):
            out += [f"### `{name}`", "", "```python", _signature(obj), "```", "", _doc(obj), ""]
    out += ["### Fixtures (pytest plugin `magline.testing.plugin`)", ""]
    # pytest wraps a fixture in its own object (not a function): every public ``magline_*`` name is one
    for name in sorted(n for n in dir(plugin) if n.startswith("magline_")):
        out += [f"- `{name}`: {_doc(getattr(plugin, name))}"]
    return [*out, ""]


def generate() -> str:
    from magline.core import dut
    from magline.core.results import contract
    from magline.plugin import DutBackend, FieldSource, Motion, PowerControl, ResultSink
    from magline.testing.conformance import REQUIRED_DUT_CAPABILITIES

    lines = [HEADER, *hooks_section(), *protocol_section("DUT backend", DutBackend),
             *capabilities_section(dut, "DUT backend", "DutBackend", REQUIRED_DUT_CAPABILITIES,
                                   "magline.testing.check_dut_backend"), *protocol_section("Result sink", ResultSink),
             *capabilities_section(contract, "result sink", "ResultSink"),
             *protocol_section("Field source", FieldSource),
             *protocol_section("Power control", PowerControl), *protocol_section("Motion", Motion),
             *types_section(), *testing_section(), *face_section()]
    return "\n".join(lines).rstrip() + "\n"


if __name__ == "__main__":
    print(generate(), end="")
