"""The options each plugin takes in a station file, as reference tables read off the plugins' own options models.

Why from the models: a table written by hand goes stale the day an option is added; the models are what
``magline check`` validates against, so a table made from them says exactly what a station file may hold —
each option's type, default, bounds and what it is for: the field's ``description``, else the docstring
written under it in the model's source.  Read here, when a table is asked for, not by pydantic's
``use_attribute_docstrings`` at every import: parsing the models' source cost every ``magline check`` and
``run`` about 60 ms of its start.  ``magline plugins --options`` prints them for whatever is installed,
third-party plugins included; ``docs/plugin-options.md`` holds magline's own
(``python -m magline.core.station.options_reference > docs/plugin-options.md``).
"""

from __future__ import annotations

import ast
import inspect
import itertools
import textwrap
import types
import typing
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Literal

from pydantic import BaseModel
from pydantic_core import PydanticUndefined

if TYPE_CHECKING:
    from pydantic.fields import FieldInfo

    from magline.core.plugins import Plugins

# each kind of registered name: its heading and where its options go in a station file, in a station file's
# order (top to bottom), which the reference follows
KINDS = {
    "dut backend": ("DUT backends", "products.<part>.options (backend: {name})"),
    "power control": ("Power controls", "products.<part>.power.options (method: {name})"),
    "field source": ("Field sources", "field_source.options (type: {name})"),
    "motion": ("Motions", "motion.options (type: {name})"),
    "current source": ("Current sources", "current_source.options (type: {name})"),
    "result sink": ("Result sinks", "results[].options (sink: {name})"),
    "plugin options": ("Plugin sections", "plugins.{name}"),
}


@dataclass(frozen=True)
class OptionRow:
    """One option of a model: its dotted name in the station file (``[]`` for each item of a list)."""

    name: str
    kind: str
    default: str
    bounds: str
    meaning: str


def option_rows(model: type[BaseModel], prefix: str = "") -> list[OptionRow]:
    """Every option of ``model``, a nested model's options under its field's name."""
    rows: list[OptionRow] = []
    written = attribute_docstrings(model)
    for name, field in model.model_fields.items():
        key = prefix + (field.alias or name)
        kind = PATH_WORDS if _is_station_path(field) else type_words(field.annotation)
        meaning = inspect.cleandoc(field.description or written.get(name, ""))
        rows.append(OptionRow(key, kind, _default(field), _bounds([*field.metadata, *_optional_metadata(field)]),
                              meaning))
        for nested, suffix in _nested_models(field.annotation):
            rows += option_rows(nested, f"{key}{suffix}.")
    return rows


def attribute_docstrings(model: type) -> dict[str, str]:
    """The docstring written under each annotated attribute of ``model`` and of the classes it derives from (a
    subclass's own first), by attribute name; none where the source cannot be read."""
    found: dict[str, str] = {}
    for cls in reversed(model.__mro__):
        if cls in (BaseModel, object) or not issubclass(cls, BaseModel):
            continue
        try:
            tree = ast.parse(textwrap.dedent(inspect.getsource(cls)))
        except (OSError, TypeError, SyntaxError):
            continue
        body = tree.body[0].body if tree.body and isinstance(tree.body[0], ast.ClassDef) else []
        for statement, following in itertools.pairwise(body):
            if (isinstance(statement, ast.AnnAssign) and isinstance(statement.target, ast.Name)
                    and isinstance(following, ast.Expr) and isinstance(following.value, ast.Constant)
                    and isinstance(following.value.value, str)):
                found[statement.target.id] = following.value.value
    return found


def type_words(annotation: Any) -> str:
    """An annotation as a station file's author reads it: ``number``, ``list of text``, ``"cw" or "ccw"``."""
    origin, args = typing.get_origin(annotation), typing.get_args(annotation)
    if origin is typing.Annotated:
        return _annotated_words(annotation, args)
    if origin in (typing.Union, types.UnionType):
        words = [type_words(arg) for arg in args if arg is not type(None)]
        return " or ".join(words) + (" or null" if type(None) in args else "")
    if origin is Literal:
        return " or ".join(f'"{a}"' if isinstance(a, str) else repr(a) for a in args)
    if origin is list:
        return f"list of {type_words(args[0])}" if args else "list"
    if origin is dict:
        return f"mapping of {type_words(args[0])} to {type_words(args[1])}" if args else "mapping"
    if isinstance(annotation, type) and issubclass(annotation, BaseModel):
        return "mapping (below)"
    plain = {float: "number", int: "integer", str: "text", bool: "true or false"}
    return plain.get(annotation) or getattr(annotation, "__name__", str(annotation))


PATH_WORDS = "path (a relative one is beside the station file)"


def _is_station_path(field: FieldInfo) -> bool:
    """A :data:`~magline.plugin.StationPath` option (pydantic keeps its validator in the field's metadata)."""
    from magline.core.station.paths import StationPath

    return typing.get_args(StationPath)[1] in field.metadata


def _annotated_words(annotation: Any, args: tuple) -> str:
    from magline.core.station.paths import StationPath

    if annotation == StationPath:
        return PATH_WORDS
    words = type_words(args[0])
    bounds = _bounds(args[1:])
    return f"{words} ({bounds})" if bounds else words


def _optional_metadata(field: FieldInfo) -> list[Any]:
    """The constraints of an optional option's value (``Annotated[float, Field(ge=…)] | None``): pydantic keeps
    them on the union's member, not on the field."""
    annotation = field.annotation
    if typing.get_origin(annotation) not in (typing.Union, types.UnionType):
        return []
    return [m for arg in typing.get_args(annotation) if typing.get_origin(arg) is typing.Annotated
            for item in typing.get_args(arg)[1:] for m in getattr(item, "metadata", [item])]


def _bounds(metadata: Any) -> str:
    """A field's constraints (pydantic's ``Field(gt=…, min_length=…)`` metadata) in words."""
    parts = []
    for attr, fmt in (("gt", "> {}"), ("ge", "≥ {}"), ("lt", "< {}"), ("le", "≤ {}")):
        parts += [fmt.format(_number(getattr(m, attr))) for m in metadata if getattr(m, attr, None) is not None]
    least = [m.min_length for m in metadata if getattr(m, "min_length", None) is not None]
    most = [m.max_length for m in metadata if getattr(m, "max_length", None) is not None]
    if least and most and least == most:
        parts.append(f"{least[0]} items")
    else:
        parts += [f"at least {n} items" for n in least] + [f"at most {n} items" for n in most]
    return ", ".join(parts)


def _number(value: Any) -> str:
    return f"{value:g}" if isinstance(value, float) else str(value)


def _default(field: FieldInfo) -> str:
    if field.default_factory is not None:
        made = field.default_factory()  # type: ignore[call-arg]
        return "(below)" if isinstance(made, BaseModel) else _shown(made)
    if field.default is PydanticUndefined:
        return "required"
    return _shown(field.default)


def _shown(value: Any) -> str:
    if value is None:
        return "none"
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, str):
        return f'"{value}"'
    if isinstance(value, float):
        return _number(value)
    return str(value).replace("'", '"')


def _nested_models(annotation: Any) -> list[tuple[type[BaseModel], str]]:
    """The models inside an annotation, each with how its options are named under the field: ``.`` for a
    mapping, ``[]`` for each item of a list."""
    origin, args = typing.get_origin(annotation), typing.get_args(annotation)
    if isinstance(annotation, type) and issubclass(annotation, BaseModel):
        return [(annotation, "")]
    if origin is typing.Annotated:
        return _nested_models(args[0])
    if origin in (typing.Union, types.UnionType):
        return [found for arg in args for found in _nested_models(arg)]
    if origin is list and args:
        return [(model, "[]" + suffix) for model, suffix in _nested_models(args[0])]
    return []


def _order(kind: str) -> tuple[int, str]:
    """Kinds in :data:`KINDS`' order, any other after them."""
    known = list(KINDS)
    return (known.index(kind), kind) if kind in known else (len(known), kind)


def markdown_table(model: type[BaseModel]) -> list[str]:
    """``model``'s options as a Markdown table."""
    lines = ["| option | type | default | what it is |", "|---|---|---|---|"]
    for row in option_rows(model):
        kind = row.kind + (f"; {row.bounds}" if row.bounds else "")
        lines.append(f"| `{row.name}` | {_cell(kind)} | {_cell(row.default)} | {_cell(row.meaning)} |")
    return lines


def _cell(text: str) -> str:
    return " ".join(text.split()).replace("|", "\\|")


def options_reference(plugins: Plugins, distributions: set[str] | None = None) -> str:
    """Every registered name that takes options, by kind, with its table; ``distributions``: only names
    registered by plugins from these distributions (None: every plugin loaded)."""
    lines: list[str] = []
    by_kind: dict[str, list[tuple[str, type[BaseModel], str]]] = {}
    for (kind, name), model in sorted(plugins.option_models.items()):
        by = plugins.registered_by[(kind, name)]
        dist, version = plugins.versions.get(by, (None, None))
        if distributions is not None and dist not in distributions:
            continue
        source = f"plugin `{by}`" + (f" ({dist} {version})" if dist is not None and dist != "magline" else "")
        by_kind.setdefault(kind, []).append((name, model, source))
    for kind, entries in sorted(by_kind.items(), key=lambda item: _order(item[0])):
        heading, where_of = KINDS.get(kind, (kind, "{name}"))
        lines += ["", f"## {heading}"]
        for name, model, source in entries:
            where = where_of.format(name=name)
            lines += ["", f"### `{name}`", "", f"In a station file: `{where}`. Registered by {source}.", ""]
            lines += markdown_table(model) if model.model_fields else ["Takes no options: any key under its "
                                                                        "`options` is an error."]
    return "\n".join(lines).lstrip("\n") + "\n"


HEADER = """# Plugin options — reference

What each of magline's own plugins takes in a station file, read off the options models that `magline check`
validates a station file against: a name not listed here, a value of the wrong type or out of its bounds is an
error naming the file, the key and the line.  `magline plugins --options` prints the same tables for every
plugin installed, third-party plugins included.  Durations are in seconds (`_s`), currents in amperes (`_a`),
fields in microtesla (`_ut`), angles in degrees (`_deg`).

"""


def main() -> None:
    from magline.core.plugins import load_plugins

    print(HEADER + options_reference(load_plugins(), {"magline"}), end="")


if __name__ == "__main__":
    main()
