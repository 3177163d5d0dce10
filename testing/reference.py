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
when this file is not current.  Start with the README's "Writing a plugin"; this page is the
exact contract.

A plugin is a module with `@hookimpl` functions (`from magline.core.plugins import hookimpl`),
listed under the `magline` entry-point group of its distribution.  Registration hooks take
`register(name, factory, options=Model)`: with a pydantic `Model`, `magline check` validates the
station file's `options` for that name (file, key and line) and the factory receives the validated
model (result sinks; DUT backends and power controls receive their station entry).
"""


def _signature(fn: Any) -> str:
    return f"{fn.__name__}{inspect.signature(fn)}".replace("'", "")


def _doc(obj: Any) -> str:
    return inspect.cleandoc(obj.__doc__ or "(undocumented)")


def hooks_section() -> list[str]:
    from magline.core import hookspecs

    out = ["## Hooks", "", _doc(hookspecs), ""]
    for name, fn in inspect.getmembers(hookspecs, inspect.isfunction):
        if not name.startswith("magline_"):
            continue
        opts = getattr(fn, "magline_spec", {}) or {}
        flag = " — `firstresult`: the first non-None answer wins" if opts.get("firstresult") else ""
        out += [f"### `{name}`{flag}", "", "```python", _signature(fn), "```", "", _doc(fn), ""]
    return out


def protocol_section(title: str, cls: Any) -> list[str]:
    out = [f"## {title}: `{cls.__module__}.{cls.__qualname__}`", "", _doc(cls), ""]
    module = inspect.getmodule(cls)
    if module is not None and module.__doc__ and cls.__doc__ is None:
        out[-2] = inspect.cleandoc(module.__doc__)
    for name, member in cls.__dict__.items():
        if name.startswith("_") or not callable(member):
            continue
        out += [f"### `{name}`", "", "```python", _signature(member), "```", "", _doc(member), ""]
    return out


def testing_section() -> list[str]:
    import magline.testing as kit
    from magline.testing import plugin

    out = ["## Testing your plugin: `magline.testing`", "", _doc(kit), ""]
    for name in kit.__all__:
        obj = getattr(kit, name)
        if inspect.isfunction(obj):
            out += [f"### `{name}`", "", "```python", _signature(obj), "```", "", _doc(obj), ""]
    out += ["### Fixtures (pytest plugin `magline.testing.plugin`)", ""]
    for name, fn in inspect.getmembers(plugin, inspect.isfunction):
        if name.startswith("magline_"):
            out += [f"- `{name}`: {_doc(fn)}"]
    return [*out, ""]


def generate() -> str:
    from magline.core.dut import DutBackend
    from magline.core.field import FieldSource
    from magline.core.motion import Motion
    from magline.core.power import PowerControl
    from magline.core.results.contract import ResultSink

    lines = [HEADER, *hooks_section(), *protocol_section("DUT backend", DutBackend),
             *protocol_section("Result sink", ResultSink), *protocol_section("Field source", FieldSource),
             *protocol_section("Power control", PowerControl), *protocol_section("Motion", Motion),
             *testing_section()]
    return "\n".join(lines).rstrip() + "\n"


if __name__ == "__main__":
    print(generate(), end="")
