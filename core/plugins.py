"""The plugin manager: loads every plugin from the ``magline`` entry-point group.

Built-ins (core phases, results store, field sources, the mock/px4/ardupilot/helmholtz plugins)
are listed in magline's own ``pyproject.toml`` under that group, so they load exactly like a
third-party plugin.  ``MAGLINE_DISABLE_PLUGINS=name1,name2`` switches entry points off by name.
After loading, ``check_pending()`` rejects any hook implementation that matches no spec, so a
misspelt hook fails at start-up instead of being silently ignored.

The :class:`Plugins` façade lets the core read like the procedure it runs
(``plugins.dut_backend(name)``) instead of reaching into ``pm.hook`` everywhere.
"""

from __future__ import annotations

import logging
import os
import re
from collections.abc import Callable, Iterator, Mapping
from importlib import import_module
from importlib.metadata import Distribution, entry_points
from types import ModuleType
from typing import TYPE_CHECKING, Any

import pluggy

from magline.core import hookspecs

if TYPE_CHECKING:
    from pathlib import Path

    from magline.core.dut import DutFactory
    from magline.core.measurements import DeclaredMeasurement

hookimpl = pluggy.HookimplMarker("magline")
ENTRY_POINT_GROUP = "magline"
log = logging.getLogger("magline.plugins")
DISABLE_ENV = "MAGLINE_DISABLE_PLUGINS"


def implementer(impl: Any) -> str:
    """A plugin's name; one registered without a name (a test's or an application's object) by its class."""
    return impl.plugin_name if not impl.plugin_name.isdigit() else type(impl.plugin).__name__


class PluginError(RuntimeError):
    """A plugin could not be loaded or registered something invalid."""


# where a registered model or factory lives: "package.module:Name" (nested in a class: "package.module:Outer.Inner")
_PLACE = re.compile(r"^[A-Za-z_]\w*(\.[A-Za-z_]\w*)*:[A-Za-z_]\w*(\.[A-Za-z_]\w*)*$")


def _object_at(place: str, what: str) -> object:
    """What ``"package.module:Name"`` names, imported now; ``what`` says whose it is when it cannot be."""
    module, _, qualname = place.partition(":")
    try:
        found: object = import_module(module)
        for part in qualname.split("."):
            found = getattr(found, part)
    except Exception as exc:  # a plugin's broken module must say whose it is
        raise PluginError(f"{what} cannot be imported: {type(exc).__name__}: {exc}") from exc
    return found


class FactoryAt:
    """A factory registered by where it lives (``register(name, "package.module:create", ...)``): imported at
    its first call, so that registering costs no import of what only a unit's run uses."""

    def __init__(self, place: str, what: str) -> None:
        self.place, self._what, self._factory = place, what, None

    def __call__(self, *args: Any, **kwargs: Any) -> Any:
        if self._factory is None:
            factory = _object_at(self.place, self._what)
            if not callable(factory):
                raise PluginError(f"{self._what} is not callable")
            self._factory = factory
        return self._factory(*args, **kwargs)

    def __repr__(self) -> str:
        return f"FactoryAt({self.place!r})"


class OptionModels(Mapping[tuple[str, str], type]):
    """``(kind, name) → model``: the options models plugins registered, each imported the first time it is read.

    A plugin names its model either as the class (``options=AcmeOptions``) or as where it lives
    (``options="acme.options:AcmeOptions"``).  Why the second: every command registers every plugin, and
    importing magline's own twelve models (their modules, some with their rig's code) cost every ``magline
    check`` 16 ms of its 0.18 s on one machine (``benchmarks/cli_start.py``), for backends and rigs its station
    file never names; named by place, a model is imported when a station file uses its name, or a reference
    table lists it."""

    def __init__(self) -> None:
        self._declared: dict[tuple[str, str], type | str] = {}
        self._by: dict[tuple[str, str], str] = {}

    def declare(self, key: tuple[str, str], options: object, by: str) -> None:
        """Keep ``options`` (a class, or ``"module:Class"``) for ``key``, registered by plugin ``by``; a
        place is checked for its form now and imported when first read."""
        if isinstance(options, str):
            if not _PLACE.match(options):
                raise PluginError(f"plugin {by!r}: the options of {key[0]} {key[1]!r} are named "
                                  f"{options!r}; a model is named 'package.module:Class'")
        elif not isinstance(options, type):
            raise PluginError(f"plugin {by!r}: the options of {key[0]} {key[1]!r} must be a pydantic model "
                              f"class or 'package.module:Class', not {type(options).__name__}")
        self._declared[key], self._by[key] = options, by

    def class_name(self, key: tuple[str, str]) -> str:
        """The model's class name, without importing it (for ``magline plugins``)."""
        declared = self._declared[key]
        return declared.rpartition(":")[2].rpartition(".")[2] if isinstance(declared, str) else declared.__name__

    def __getitem__(self, key: tuple[str, str]) -> type:
        declared = self._declared[key]
        if isinstance(declared, type):
            return declared
        model = self._imported(key, declared)
        self._declared[key] = model  # imported once: the class from then on
        return model

    def _imported(self, key: tuple[str, str], place: str) -> type:
        from pydantic import BaseModel

        what = f"plugin {self._by[key]!r}: the options model {place!r} of {key[0]} {key[1]!r}"
        model = _object_at(place, what)
        if not (isinstance(model, type) and issubclass(model, BaseModel)):
            raise PluginError(f"{what} is not a pydantic model")
        return model

    def __contains__(self, key: object) -> bool:
        return key in self._declared  # asking whether a model was registered imports none

    def __iter__(self) -> Iterator[tuple[str, str]]:
        return iter(self._declared)

    def __len__(self) -> int:
        return len(self._declared)


class Plugins:
    """The loaded plugins and their registries (DUT backends, field sources, result sinks, power controls, motions,
    current sources).

    The registries are filled by the plugins' ``magline_register_*`` hooks, at construction unless asked
    ``register=False``; then on :meth:`register` or the first use of any of them.  Why on demand: ``magline
    --help`` needs only the plugins' commands, and registering imports each plugin's options models (pydantic)
    that no help text uses."""

    # what the registration hooks fill: asking for any of them registers first
    _REGISTRIES = frozenset({"dut_backends", "field_sources", "result_sinks", "power_controls", "motions",
                             "current_sources", "option_models", "calibration_stores", "registered_by",
                             "measurements", "plugin_sections"})

    def __init__(self, pm: pluggy.PluginManager, dists: dict[str, Distribution] | None = None, *,
                 register: bool = True) -> None:
        self.pm = pm
        self.hook = pm.hook
        self._dists = dists or {}  # plugin name → the distribution its entry point came from
        self._versions: dict[str, tuple[str, str]] | None = None
        self._registered, self._failed = False, None
        if register:
            self.register()

    def __getattr__(self, name: str) -> Any:
        """A registry asked before :meth:`register` ran: registered now (only missing attributes come here)."""
        if name in Plugins._REGISTRIES and "_registered" in self.__dict__:
            self.register()
            return self.__dict__[name]
        raise AttributeError(f"{type(self).__name__!r} object has no attribute {name!r}")

    def register(self) -> None:
        """Call every plugin's registration hooks, once: a name registered twice, a bad ``stores=`` or a
        measurement declared wrongly is a :class:`PluginError` here — and again at every later use, never
        half a registry taken for the whole."""
        if self._registered:
            if self._failed is not None:
                raise PluginError(f"the plugins' registration failed: {self._failed}")
            return
        self._registered, self._failed = True, None
        try:
            self._register_all()
        except Exception as exc:
            for name in Plugins._REGISTRIES:  # what was filled before the failure is no registry
                self.__dict__.pop(name, None)
            self._failed = exc
            raise

    def _register_all(self) -> None:
        self.dut_backends: dict[str, DutFactory] = {}
        self.field_sources: dict[str, Callable[..., Any]] = {}
        self.result_sinks: dict[str, Callable[..., Any]] = {}
        self.power_controls: dict[str, Callable[..., Any]] = {}
        self.motions: dict[str, Callable[..., Any]] = {}
        self.current_sources: dict[str, Callable[..., Any]] = {}
        # options models a plugin declared at registration (``register(name, factory, options=Model)``),
        # so ``magline check`` validates a product's options before any unit is connected
        self.option_models = OptionModels()
        # where each DUT backend can keep a calibration (a product's ``persist``), each in the backend's
        # words: ``register(name, factory, stores={"parameters": "…", "factory-storage": "…"})``
        self.calibration_stores: dict[str, dict[str, str]] = {}
        # who registered each name: (kind, name) → plugin name (for ``magline plugins`` and errors)
        self.registered_by: dict[tuple[str, str], str] = {}
        self._collect("dut backend", self.dut_backends, self.hook.magline_register_dut_backends)
        self._collect("field source", self.field_sources, self.hook.magline_register_field_sources)
        self._collect("result sink", self.result_sinks, self.hook.magline_register_result_sinks)
        self._collect("power control", self.power_controls, self.hook.magline_register_power_controls)
        self._collect("motion", self.motions, self.hook.magline_register_motions)
        self._collect("current source", self.current_sources, self.hook.magline_register_current_sources)
        # the plugins' own measurements (``magline_register_measurements``), by name: what a station file may
        # limit beside magline's catalogue
        self.measurements: dict[str, DeclaredMeasurement] = {}
        self._declare_measurements()
        self.plugin_sections: dict[str, str] = {}  # section → the plugin that registered it
        self._plugin_sections()

    def _collect(self, kind: str, registry: dict[str, Any], hook: Any) -> None:
        """Call each plugin's registration hook in pluggy's order (last registered first), knowing
        which plugin registers what."""
        for impl in reversed(hook.get_hookimpls()):
            # a plugin registered without a name (a test's or an application's object) is called by its class
            by = implementer(impl)

            def register(name: str, factory: Any, options: type | None = None, _by: str = by,
                         stores: dict[str, str] | None = None) -> None:
                if not isinstance(name, str) or not name:
                    raise PluginError(f"plugin {_by!r}: a {kind} must be registered under a non-empty name")
                if name in registry:
                    raise PluginError(f"{kind} {name!r} is registered twice (by plugin "
                                      f"{self.registered_by[(kind, name)]!r} and by plugin {_by!r})")
                if isinstance(factory, str):
                    if not _PLACE.match(factory):
                        raise PluginError(f"plugin {_by!r}: the factory of {kind} {name!r} is named {factory!r}; "
                                          "a factory is a callable or 'package.module:function'")
                    factory = FactoryAt(factory, f"plugin {_by!r}: the factory {factory!r} of {kind} {name!r}")
                elif not callable(factory):
                    raise PluginError(f"plugin {_by!r}: the factory of {kind} {name!r} is not callable")
                registry[name] = factory
                self.registered_by[(kind, name)] = _by
                if options is not None:
                    self.option_models.declare((kind, name), options, _by)
                if stores is not None:
                    if kind != "dut backend" or "parameters" not in stores:
                        raise PluginError(f"plugin {_by!r}: stores= belongs to a DUT backend, and every backend "
                                          "keeps a calibration in 'parameters'")
                    self.calibration_stores[name] = dict(stores)

            impl.function(register=register)

    def _declare_measurements(self) -> None:
        from magline.core.measurements import DECLARED_MEANINGS, DeclaredMeasurement

        for impl in reversed(self.hook.magline_register_measurements.get_hookimpls()):
            by = implementer(impl)

            def register(name: str, unit: str = "", meaning: str = "",
                         possible: tuple[float, float] = (float("-inf"), float("inf")), _by: str = by) -> None:
                declared = DeclaredMeasurement(name, str(unit), str(meaning),
                                               (float(possible[0]), float(possible[1])), _by)
                problem = declared.problem()
                if problem is None and name in self.measurements:
                    problem = f"measurement {name!r} is declared by plugin {self.measurements[name].plugin!r} already"
                if problem is not None:
                    raise PluginError(f"plugin {_by!r}: {problem}")
                self.measurements[name] = declared
                self.registered_by[("measurement", name)] = _by
                if declared.meaning:
                    DECLARED_MEANINGS[name] = declared.meaning

            impl.function(register=register)

    def _plugin_sections(self) -> None:
        for impl in reversed(self.hook.magline_register_plugin_options.get_hookimpls()):
            by = implementer(impl)

            def register(section: str, options: type | str, _by: str = by) -> None:
                if not isinstance(section, str) or not section:
                    raise PluginError(f"plugin {_by!r}: a plugins: section must be registered under a non-empty name")
                if section in self.plugin_sections:
                    raise PluginError(f"plugins: section {section!r} is registered twice (by plugin "
                                      f"{self.registered_by[('plugin options', section)]!r} and by plugin {_by!r})")
                self.option_models.declare(("plugin options", section), options, _by)
                self.plugin_sections[section] = _by
                self.registered_by[("plugin options", section)] = _by

            impl.function(register=register)

    def answers(self, hook_name: str, **kwargs: Any) -> list[tuple[str, Any, Exception | None]]:
        """Each implementation of a hook called on its own, in pluggy's order, with the arguments it declares:
        ``(plugin, answer, None)``, or ``(plugin, None, the exception)`` for one that raised — one plugin's fault
        is said as its own, and the others are still heard.  An abort (a ``BaseException``) goes through."""
        out: list[tuple[str, Any, Exception | None]] = []
        for impl in reversed(getattr(self.hook, hook_name).get_hookimpls()):
            try:
                out.append((implementer(impl), impl.function(**{name: kwargs[name] for name in impl.argnames
                                                                   if name in kwargs}), None))
            except Exception as exc:
                out.append((implementer(impl), None, exc))
        return out

    def notify(self, hook_name: str, faults: list[str] | None = None, **kwargs: Any) -> None:
        """Call a listener hook's implementations one by one: one that raises is said (which plugin, which
        hook, the message) in ``faults`` and the log, and the others still hear.  Why: a listener — a plant
        feed whose file is not writable, a screen gone — must never touch the verdict, the exit code or a
        batch; a results store failing is not a listener (``magline_record_unit``) and stays an ERROR.  An
        abort (``UnitAborted``, a ``BaseException``) still goes through."""
        for plugin, _, exc in self.answers(hook_name, **kwargs):
            if exc is not None:
                text = f"plugin {plugin!r}, {hook_name}: {type(exc).__name__}: {exc}"
                log.warning("a listener failed (the unit's verdict stands): %s", text)
                if faults is not None:
                    faults.append(text)

    def options(self, kind: str, name: str, raw: dict[str, Any], owner: str,
                station_dir: Path | str | None = None) -> Any:
        """A factory's options: ``raw`` validated against the model the plugin registered for
        ``(kind, name)`` (the raw mapping when it registered none), a :data:`~magline.plugin.StationPath`
        in them resolved against ``station_dir``.  ``magline check`` and the commands that load a station
        report the same problems earlier, with file and line."""
        from magline.core.dut import validated_options

        model = self.option_models.get((kind, name))
        return validated_options(model, raw, owner, station_dir) if model is not None else raw

    @property
    def versions(self) -> dict[str, tuple[str, str]]:
        """Plugin name → (distribution, version).  Read on first use: parsing each distribution's metadata
        (and importing the e-mail parser it is written in) is a tenth of what ``magline --help`` took."""
        if self._versions is None:
            by_dist: dict[int, tuple[str, str]] = {}
            for dist in self._dists.values():
                if id(dist) not in by_dist:
                    metadata = dist.metadata
                    by_dist[id(dist)] = (metadata["Name"], metadata["Version"])
            self._versions = {name: by_dist[id(dist)] for name, dist in self._dists.items()}
        return self._versions

    def describe(self) -> list[dict[str, Any]]:
        """Loaded plugins with their distribution and version, the hooks each implements and the
        names each registered (for ``magline plugins``)."""
        out = []
        for name, plugin in self.pm.list_name_plugin():
            if plugin is None:
                continue
            hooks = sorted(h.name for h in self.pm.get_hookcallers(plugin) or [])
            dist, version = self.versions.get(name, (None, None))
            registers = sorted(f"{kind}: {what}" for (kind, what), by in self.registered_by.items() if by == name)
            out.append({"name": name, "module": getattr(plugin, "__name__", repr(plugin)), "distribution": dist,
                        "version": version, "hooks": hooks, "registers": registers})
        return sorted(out, key=lambda d: d["name"])

    def registry(self) -> dict[str, dict[str, dict[str, Any]]]:
        """Every registered name by kind, with the plugin that registered it and its version."""
        out: dict[str, dict[str, dict[str, Any]]] = {}
        for (kind, name), by in sorted(self.registered_by.items()):
            dist, version = self.versions.get(by, (None, None))
            options = self.option_models.class_name((kind, name)) if (kind, name) in self.option_models else None
            out.setdefault(kind, {})[name] = {"plugin": by, "distribution": dist, "version": version,
                                              "options": options}
        return out


def load_plugins(extra: list[ModuleType | object] | None = None, *, register: bool = True) -> Plugins:
    """Create the manager, load entry points (minus disabled ones), add ``extra``, check, return; with
    ``register=False`` the plugins' registration hooks run when a registry is first used (:class:`Plugins`)."""
    pm = pluggy.PluginManager("magline")
    pm.add_hookspecs(hookspecs)
    disabled = {n.strip() for n in os.environ.get(DISABLE_ENV, "").split(",") if n.strip()}
    dists: dict[str, Distribution] = {}
    for ep in entry_points(group=ENTRY_POINT_GROUP):
        if ep.name in disabled or pm.has_plugin(ep.name):
            continue
        try:
            plugin = ep.load()
        except Exception as exc:  # a broken third-party plugin must say who it is
            raise PluginError(f"plugin {ep.name!r} ({ep.value}) failed to load: {exc}") from exc
        pm.register(plugin, name=ep.name)
        dist = getattr(ep, "dist", None)
        if dist is not None:
            dists[ep.name] = dist
    for plugin in extra or []:
        pm.register(plugin)
    try:
        pm.check_pending()
    except pluggy.PluginValidationError as exc:
        raise PluginError(f"unknown hook implementation: {exc}") from exc
    return Plugins(pm, dists, register=register)
