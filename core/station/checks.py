"""Every problem of a station file in one pass: schema, then the names and options that only the
loaded plugins can judge (backends, power controls, field sources, result sinks).

Why one pass: an engineer editing a station file should see all of its problems at once, each as
``file:line: key: what is wrong``, not one round of edit-and-check per problem.  The plugin checks
read the YAML data directly, so they run even when the schema has complaints of its own.
"""

from __future__ import annotations

import difflib
from collections.abc import Iterable
from typing import TYPE_CHECKING, Any

import yaml
from pydantic import BaseModel, ValidationError

from magline.core.links.addresses import names_a_vehicle_link
from magline.core.plugins import Plugins
from magline.core.station.loader import StationError, dotted, line_of, load_station_text, safe_data
from magline.core.station.shared_stores import results_entries, shared_store_problems

if TYPE_CHECKING:
    from magline.core.station.schema import Station


def did_you_mean(word: str, choices: Iterable[str]) -> str:
    """`` (did you mean 'backend'?)`` when a choice is close to ``word``, else nothing."""
    close = difflib.get_close_matches(str(word), [str(c) for c in choices], n=1, cutoff=0.6)
    return f" (did you mean {close[0]!r}?)" if close else ""


def station_problems(text: str, name: str, plugins: Plugins) -> tuple[Station | None, list[str]]:
    """The station (None when the schema refuses it) and every problem found, in file order."""
    try:
        station, problems = load_station_text(text, name, plugins.measurements), []
    except StationError as exc:
        station, problems = None, list(exc.problems)
    try:
        data = safe_data(text)
    except yaml.YAMLError:
        return station, problems  # a syntax error was reported by the loader; nothing else to read
    if isinstance(data, dict):
        problems += _plugin_problems(data, text, name, plugins) + shared_store_problems(data, text, name)
    return station, sorted(dict.fromkeys(problems), key=_line_number)


def _line_number(problem: str) -> int:
    parts = problem.split(":")
    return int(parts[1]) if len(parts) > 2 and parts[1].isdigit() else 0


def _plugin_problems(data: dict, text: str, name: str, plugins: Plugins) -> list[str]:
    out: list[str] = []

    def unknown(path: tuple, what: str, value: Any, registry: dict) -> None:
        out.append(f"{name}:{line_of(text, path)}: {dotted(path)}: unknown {what} {value!r}"
                   f"{did_you_mean(value, registry)}; loaded: {', '.join(sorted(registry))}")

    def power_problems(power: Any, where: tuple) -> None:
        if not isinstance(power, dict) or not isinstance(method := power.get("method", "link-reboot"), str):
            return
        if method not in plugins.power_controls:
            unknown((*where, "method"), "power control", method, plugins.power_controls)
        out.extend(_option_problems(plugins, ("power control", method), power.get("options"), (*where, "options"),
                                    text, name))

    products = data.get("products")
    for part, product in (products.items() if isinstance(products, dict) else ()):
        if not isinstance(product, dict):
            continue
        backend = product.get("backend")
        if isinstance(backend, str):
            if backend not in plugins.dut_backends:
                unknown(("products", part, "backend"), "DUT backend", backend, plugins.dut_backends)
            out += _option_problems(plugins, ("dut backend", backend), product.get("options"),
                                    ("products", part, "options"), text, name)
            store = product.get("persist", "parameters")
            stores = plugins.calibration_stores.get(backend, {"parameters": ""})
            if backend in plugins.dut_backends and isinstance(store, str) and store not in stores:
                why = "; ".join(f"{kept}: {words}" for kept, words in stores.items() if words)
                out.append(f"{name}:{line_of(text, ('products', part, 'persist'))}: products.{part}.persist: the "
                           f"{backend} backend has no {store} (it keeps a calibration in {', '.join(stores)}"
                           f"{' — ' + why if why else ''})")
        out += _connection_problems(plugins, backend, product.get("connection"), ("products", part, "connection"),
                                    text, name)
        power_problems(product.get("power"), ("products", part, "power"))
    linked: dict[str, Any] = {}  # a vehicle link → the slot that has it
    for index, slot in enumerate(data.get("slots") or []):
        product = products.get(slot.get("part")) if isinstance(slot, dict) and isinstance(products, dict) else None
        if isinstance(slot, dict):
            power_problems(slot.get("power"), ("slots", index, "power"))  # a slot's own power control
        link = (slot.get("connection") if isinstance(slot, dict) else None) or \
            (product.get("connection") if isinstance(product, dict) else None)
        if isinstance(link, str) and names_a_vehicle_link(link):
            if link.strip() in linked:
                where = ("slots", index, "connection") if slot.get("connection") else ("slots", index)
                out.append(f"{name}:{line_of(text, where)}: {dotted(where)}: {link.strip()} is slot "
                           f"{linked[link.strip()]}'s link too: two slots would test one unit (each slot's unit "
                           "needs a link of its own)")
            else:
                linked[link.strip()] = slot.get("id")
        if isinstance(product, dict):
            out += _connection_problems(plugins, product.get("backend"), slot.get("connection"),
                                        ("slots", index, "connection"), text, name)
        if isinstance(product, dict) and isinstance(slot.get("options"), dict) and slot["options"]:
            merged = {**(product.get("options") or {}), **slot["options"]}
            out += _option_problems(plugins, ("dut backend", product.get("backend")), merged,
                                    ("slots", index, "options"), text, name)
    source = data.get("field_source")
    if isinstance(source, dict) and isinstance(source.get("type", "fixed"), str):
        out += _option_problems(plugins, ("field source", source.get("type", "fixed")), source.get("options"),
                                ("field_source", "options"), text, name)
    motion = data.get("motion")
    if isinstance(motion, dict) and isinstance(motion.get("type", "operator"), str):
        out += _option_problems(plugins, ("motion", motion.get("type", "operator")), motion.get("options"),
                                ("motion", "options"), text, name)
    for where, entry in results_entries(data):
        sink = entry.get("sink", "sqlite") if isinstance(entry, dict) else None
        if not isinstance(sink, str):
            continue
        if sink not in plugins.result_sinks:
            unknown((*where, "sink"), "results sink", sink, plugins.result_sinks)
        out += _option_problems(plugins, ("result sink", sink), entry.get("options"), (*where, "options"), text, name)
    current = data.get("current_source")
    if isinstance(current, dict) and isinstance(current.get("type"), str):
        out += _option_problems(plugins, ("current source", current["type"]), current.get("options"),
                                ("current_source", "options"), text, name)
    sections = data.get("plugins")
    for section, options in (sections.items() if isinstance(sections, dict) else ()):
        if section not in plugins.plugin_sections:
            unknown(("plugins", section), "plugins: section", section, plugins.plugin_sections)
        else:
            out += _option_problems(plugins, ("plugin options", section), options, ("plugins", section), text, name)
    for section, key, what, registry in (("field_source", "type", "field source", plugins.field_sources),
                                         ("motion", "type", "motion", plugins.motions),
                                         ("current_source", "type", "current source", plugins.current_sources)):
        block = data.get(section)
        value = block.get(key) if isinstance(block, dict) else None
        if isinstance(value, str) and value not in registry:
            unknown((section, key), what, value, registry)
    return out


def _connection_problems(plugins: Plugins, backend: Any, connection: Any, where: tuple, text: str,
                         name: str) -> list[str]:
    """What the backends' plugins say of a product's or a slot's ``connection`` (magline_connection_problem)."""
    if not isinstance(backend, str) or not isinstance(connection, str):
        return []
    said = [f"plugin {plugin!r} could not judge it: {type(exc).__name__}: {exc}" if exc is not None else answer
            for plugin, answer, exc in plugins.answers("magline_connection_problem", backend=backend,
                                                       connection=connection)]
    return [f"{name}:{line_of(text, where)}: {dotted(where)}: {problem}" for problem in said if problem]


def _option_problems(plugins: Plugins, key: tuple[str, str], options: Any, where: tuple, text: str,
                     name: str) -> list[str]:
    """A plugin's declared options model applied to the station file's options, one line per problem."""
    model: type[BaseModel] | None = plugins.option_models.get(key)
    if model is None or not isinstance(options, dict | None):
        return []
    try:
        model.model_validate(options or {})
    except ValidationError as exc:
        out = []
        for err in exc.errors():
            path = (*where, *err["loc"])
            kind = err["type"]
            if kind == "extra_forbidden" and not model.model_fields:
                msg = f"unknown key: {key[0]} {key[1]!r} takes no options"
            elif kind == "extra_forbidden":  # the core's own words for a plugin's options too
                msg = "unknown key" + did_you_mean(err["loc"][-1], model.model_fields)
            elif kind == "missing":
                msg = "required key is missing"
            else:
                msg = err["msg"].removeprefix("Value error, ")
                if "input" in err and kind.endswith("_type"):
                    msg += f" (got {type(err['input']).__name__} {err['input']!r})"
            line = line_of(text, path if kind != "missing" else path[:-1])
            out.append(f"{name}:{line}: {dotted(path)}: {msg}")
        return out
    return []
