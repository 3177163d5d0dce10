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

import os
from collections.abc import Callable
from importlib.metadata import entry_points
from types import ModuleType
from typing import Any

import pluggy

from magline.core import hookspecs
from magline.core.dut import DutFactory

hookimpl = pluggy.HookimplMarker("magline")
ENTRY_POINT_GROUP = "magline"
DISABLE_ENV = "MAGLINE_DISABLE_PLUGINS"


class PluginError(RuntimeError):
    """A plugin could not be loaded or registered something invalid."""


class Plugins:
    """The loaded plugins and their registries (DUT backends, field sources, result sinks, power controls, motions)."""

    def __init__(self, pm: pluggy.PluginManager) -> None:
        self.pm = pm
        self.hook = pm.hook
        self.dut_backends: dict[str, DutFactory] = {}
        self.field_sources: dict[str, Callable[..., Any]] = {}
        self.result_sinks: dict[str, Callable[..., Any]] = {}
        self.power_controls: dict[str, Callable[..., Any]] = {}
        self.motions: dict[str, Callable[..., Any]] = {}
        # options models a plugin declared at registration (``register(name, factory, options=Model)``),
        # so ``magline check`` validates a product's options before any unit is connected
        self.option_models: dict[tuple[str, str], type] = {}
        self._collect("dut backend", self.dut_backends, self.hook.magline_register_dut_backends)
        self._collect("field source", self.field_sources, self.hook.magline_register_field_sources)
        self._collect("result sink", self.result_sinks, self.hook.magline_register_result_sinks)
        self._collect("power control", self.power_controls, self.hook.magline_register_power_controls)
        self._collect("motion", self.motions, self.hook.magline_register_motions)

    def _collect(self, kind: str, registry: dict[str, Any], hook: Any) -> None:
        def register(name: str, factory: Any, options: type | None = None) -> None:
            if not isinstance(name, str) or not name:
                raise PluginError(f"a {kind} must be registered under a non-empty name")
            if name in registry:
                raise PluginError(f"{kind} {name!r} is registered twice")
            registry[name] = factory
            if options is not None:
                self.option_models[(kind, name)] = options

        hook(register=register)

    def describe(self) -> list[dict[str, Any]]:
        """Loaded plugins with the hooks each implements (for ``magline plugins``)."""
        out = []
        for name, plugin in self.pm.list_name_plugin():
            if plugin is None:
                continue
            hooks = sorted(h.name for h in self.pm.get_hookcallers(plugin) or [])
            out.append({"name": name, "module": getattr(plugin, "__name__", repr(plugin)), "hooks": hooks})
        return sorted(out, key=lambda d: d["name"])


def load_plugins(extra: list[ModuleType | object] | None = None) -> Plugins:
    """Create the manager, load entry points (minus disabled ones), add ``extra``, check, return."""
    pm = pluggy.PluginManager("magline")
    pm.add_hookspecs(hookspecs)
    disabled = {n.strip() for n in os.environ.get(DISABLE_ENV, "").split(",") if n.strip()}
    for ep in entry_points(group=ENTRY_POINT_GROUP):
        if ep.name in disabled or pm.has_plugin(ep.name):
            continue
        try:
            plugin = ep.load()
        except Exception as exc:  # a broken third-party plugin must say who it is
            raise PluginError(f"plugin {ep.name!r} ({ep.value}) failed to load: {exc}") from exc
        pm.register(plugin, name=ep.name)
    for plugin in extra or []:
        pm.register(plugin)
    try:
        pm.check_pending()
    except pluggy.PluginValidationError as exc:
        raise PluginError(f"unknown hook implementation: {exc}") from exc
    return Plugins(pm)
