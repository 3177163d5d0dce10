"""Load a station file safely and report every problem as ``file:line: key: what is wrong``.

PyYAML's SafeLoader composes the node tree (which keeps line numbers) and constructs plain
Python data from it; pydantic validates; each error's key path is mapped back to its node.
"""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path
from types import UnionType
from typing import Annotated, Any, Union, get_args, get_origin

import yaml
from pydantic import BaseModel, ValidationError

from magline.core.station.schema import Station

Path_ = tuple[str | int, ...]
# libyaml's parser where PyYAML carries it (its wheels do): the same safe constructor and the same marks,
# several times faster than the pure-Python parser on a station file, which every command starts by reading
SafeLoader = getattr(yaml, "CSafeLoader", yaml.SafeLoader)


class StationError(ValueError):
    """One or more problems in a station file; ``problems`` holds one line each."""

    def __init__(self, problems: list[str]) -> None:
        super().__init__("\n".join(problems))
        self.problems = problems


def read_station_text(path: str | Path) -> str:
    """The file's text, or a StationError naming the file when it cannot be read."""
    try:
        return Path(path).read_text(encoding="utf-8")
    except OSError as exc:
        raise StationError([f"{path}: cannot read station file: {exc.strerror}"]) from exc


def load_station_text(text: str, name: str, measurements: dict[str, Any] | None = None) -> Station:
    """The station file's text read and validated; every problem is said at once with file, key and line.
    ``measurements``: the loaded plugins' own measurements (``Plugins.measurements``), which its limits
    may name beside magline's."""
    loader = SafeLoader(text)
    try:
        node = loader.get_single_node()
        if node is None:
            raise StationError([f"{name}:1: the station file is empty"])
        lines: dict[Path_, int] = {}
        problems: list[str] = []
        _index(node, (), lines, problems, name)
        data = loader.construct_document(node)
    except yaml.MarkedYAMLError as exc:
        mark = exc.problem_mark or exc.context_mark
        line = mark.line + 1 if mark else 1
        raise StationError([f"{name}:{line}: YAML syntax: {exc.problem or exc.context}"]) from exc
    finally:
        loader.dispose()
    if not isinstance(data, dict):
        raise StationError([f"{name}:1: the station file must be a mapping of sections"])
    try:
        station = Station.model_validate(data, context={"measurements": measurements or {}})
    except ValidationError as exc:
        problems += [_describe(err, lines, name) for err in exc.errors()]
    if problems:
        raise StationError(problems)
    return station


def safe_data(text: str) -> Any:
    """The YAML text as plain Python data, loaded safely (no tags beyond YAML's own)."""
    return yaml.load(text, Loader=SafeLoader)


def line_of(station_text: str, key_path: Iterable[str | int]) -> int:
    """Line (1-based) of a key path in a station file's text; used for checks made after loading."""
    loader = SafeLoader(station_text)
    try:
        node = loader.get_single_node()
    finally:
        loader.dispose()
    lines: dict[Path_, int] = {}
    _index(node, (), lines, [], "")
    return _nearest(tuple(key_path), lines)


def _index(node: yaml.Node, path: Path_, lines: dict[Path_, int], problems: list[str], name: str) -> None:
    lines.setdefault(path, node.start_mark.line + 1)
    if isinstance(node, yaml.MappingNode):
        seen: set[Any] = set()
        for key_node, value_node in node.value:
            key = key_node.value
            if key in seen:
                problems.append(f"{name}:{key_node.start_mark.line + 1}: {dotted((*path, key))}: duplicate key")
            seen.add(key)
            lines[(*path, key)] = key_node.start_mark.line + 1
            _index(value_node, (*path, key), lines, problems, name)
    elif isinstance(node, yaml.SequenceNode):
        for i, item in enumerate(node.value):
            _index(item, (*path, i), lines, problems, name)


def _nearest(path: Path_, lines: dict[Path_, int]) -> int:
    while path and path not in lines:
        path = path[:-1]
    return lines.get(path, 1)


def _describe(err: Any, lines: dict[Path_, int], name: str) -> str:
    loc = tuple(p for p in err["loc"] if not (isinstance(p, str) and p.startswith("function-")))
    # pydantic adds the union member / validator name in some locations; keep only real keys
    loc = tuple(p for p in loc if p not in ("float", "int", "str", "list[float]", "[key]"))
    loc = _as_written(loc, lines)
    kind = err["type"]
    if kind == "missing":
        line = _nearest(loc[:-1], lines)
        msg = "required key is missing"
    elif kind == "extra_forbidden":
        line = _nearest(loc, lines)
        msg = "unknown key" + _did_you_mean(loc)
    else:
        line = _nearest(loc, lines)
        msg = err["msg"].removeprefix("Value error, ")
        if "input" in err and kind.endswith("_type"):
            msg += f" (got {type(err['input']).__name__} {err['input']!r})"
    key = dotted(loc) or "(top level)"
    return f"{name}:{line}: {key}: {msg}"


def _as_written(loc: Path_, lines: dict[Path_, int]) -> Path_:
    """A section that may be one item or a list (``results:``) is validated as a list: an index
    the file does not have (it wrote the single mapping) is dropped from the key path shown, as is the
    name of a union's member model."""
    out: Path_ = ()
    for part in loc:
        if isinstance(part, int) and out in lines and (*out, part) not in lines and (*out, 0) not in lines:
            continue
        if isinstance(part, str) and part[:1].isupper() and part.isidentifier() and (*out, part) not in lines:
            continue  # the union member pydantic tried (``time_skew.TimeSkew.sigma_ms``): not a key of the file
        out = (*out, part)
    return out


def dotted(path: Iterable[str | int]) -> str:
    out = ""
    for p in path:
        out += f"[{p}]" if isinstance(p, int) else (f".{p}" if out else str(p))
    return out


def _did_you_mean(loc: Path_) -> str:
    """For an unknown key: the nearest key the schema allows at that place, when one is close."""
    import difflib

    allowed = _allowed_keys(loc[:-1])
    close = difflib.get_close_matches(str(loc[-1]), allowed, n=1, cutoff=0.6)
    return f" (did you mean {close[0]!r}?)" if close else ""


def _allowed_keys(path: Path_) -> list[str]:
    """The keys the station schema accepts under ``path`` (empty when it is not a section)."""
    node: Any = Station
    for part in path:
        node = _unwrap(node)
        if isinstance(node, type) and issubclass(node, BaseModel):
            field = node.model_fields.get(str(part))
            if field is None:
                return []
            node = field.annotation
        elif get_origin(node) is dict:
            node = get_args(node)[1]
        elif get_origin(node) is list:
            node = get_args(node)[0]
        else:
            return []
    node = _unwrap(node)
    if get_origin(node) is list:  # a one-or-many section written as its single mapping (``results:``)
        node = _unwrap(get_args(node)[0])
    return list(node.model_fields) if isinstance(node, type) and issubclass(node, BaseModel) else []


def _unwrap(node: Any) -> Any:
    """Annotated[X, ...] → X; X | None → X."""
    while get_origin(node) is Annotated:
        node = get_args(node)[0]
    if get_origin(node) in (Union, UnionType):
        members = [a for a in get_args(node) if a is not type(None)]
        node = members[0] if members else node
        return _unwrap(node)
    return node
