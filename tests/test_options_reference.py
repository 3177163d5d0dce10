"""What a station file's author reads about each plugin's options: tables made from the options models that
``magline check`` validates against, for magline's own plugins (``docs/plugin-options.md``) and for whatever is
installed (``magline plugins --options``)."""

from __future__ import annotations

import sys
import textwrap

import pytest
from conftest import REPO, installed_plugin

from magline.core.cli import main
from magline.core.plugins import load_plugins
from magline.core.station.options_reference import HEADER, option_rows, options_reference


def test_the_options_reference_is_current():
    written = (REPO / "docs" / "plugin-options.md").read_text(encoding="utf-8")
    expected = HEADER + options_reference(load_plugins(), {"magline"})
    assert written == expected, ("docs/plugin-options.md is stale: run  "
                                 "python -m magline.core.station.options_reference > docs/plugin-options.md")


def test_every_option_of_magline_s_own_plugins_says_what_it_is():
    plugins = load_plugins()
    undescribed = [f"{kind} {name}: {row.name}" for (kind, name), model in plugins.option_models.items()
                   if plugins.versions.get(plugins.registered_by[(kind, name)], (None,))[0] == "magline"
                   for row in option_rows(model) if not row.meaning]
    assert plugins.option_models and not undescribed


def test_every_registered_backend_motion_power_and_current_source_has_its_table():
    text = options_reference(load_plugins(), {"magline"})
    for heading, name, where in (("DUT backends", "px4", "products.<part>.options (backend: px4)"),
                                 ("Power controls", "usb-hub", "products.<part>.power.options (method: usb-hub)"),
                                 ("Field sources", "helmholtz", "field_source.options (type: helmholtz)"),
                                 ("Motions", "turntable", "motion.options (type: turntable)"),
                                 ("Current sources", "motor-test", "current_source.options (type: motor-test)")):
        section = text.split(f"## {heading}\n", 1)[1].split("\n## ", 1)[0]
        assert f"### `{name}`\n\nIn a station file: `{where}`." in section


@pytest.fixture
def wobbler(tmp_path, monkeypatch):
    """An installed third-party distribution whose ``magline`` entry point registers a motion with options."""
    site = tmp_path / "site"
    installed_plugin(site, "wobbler_magline", "wobbler-magline", "2.3", textwrap.dedent('''
        from typing import Annotated, Literal

        from pydantic import BaseModel, ConfigDict, Field

        from magline.plugin import StationPath, hookimpl


        class Arm(BaseModel):
            model_config = ConfigDict(extra="forbid")
            reach_mm: Annotated[float, Field(gt=0, le=900)] = 450.0
            """How far the arm reaches."""


        class WobblerOptions(BaseModel):
            model_config = ConfigDict(extra="forbid")
            resource: str
            """The wobbler's controller."""
            axes: Annotated[list[float], Field(min_length=3, max_length=3)] = [1.0, 0.0, 0.0]
            """The wobble's axis | in the body."""
            mode: Literal["slow", "fast"] = "slow"
            log: StationPath = "wobble.log"
            arms: list[Arm] = []
            """The arms, in order."""
            limit_deg: float | None = Field(None, description="The largest wobble.")
            """Not this: a description given to the field comes first."""
            tilt_deg: Annotated[float, Field(ge=-90, le=90)] | None = None
            """The cradle's tilt, when it has one."""


        @hookimpl
        def magline_register_motions(register):
            register("wobbler", lambda station, options: None, options=WobblerOptions)
            register("still", lambda station, options: None, options=NoOptions)


        class NoOptions(BaseModel):
            model_config = ConfigDict(extra="forbid")
    '''))
    monkeypatch.syspath_prepend(str(site))
    yield site
    sys.modules.pop("wobbler_magline", None)


def test_a_third_party_plugin_s_options_are_printed_with_its_types_defaults_bounds_and_words(wobbler, capsys):
    assert main(["plugins", "--options"]) == 0
    out = capsys.readouterr().out
    section = out.split("### `wobbler`\n", 1)[1].split("\n### ", 1)[0].split("\n## ", 1)[0]
    assert ("In a station file: `motion.options (type: wobbler)`. Registered by plugin `wobbler` "
            "(wobbler-magline 2.3).") in section
    rows = [line for line in section.splitlines() if line.startswith("| `")]
    assert rows == [
        "| `resource` | text | required | The wobbler's controller. |",
        "| `axes` | list of number; 3 items | [1.0, 0.0, 0.0] | The wobble's axis \\| in the body. |",
        '| `mode` | "slow" or "fast" | "slow" |  |',
        '| `log` | path (a relative one is beside the station file) | "wobble.log" |  |',
        "| `arms` | list of mapping (below) | [] | The arms, in order. |",
        "| `arms[].reach_mm` | number; > 0, ≤ 900 | 450 | How far the arm reaches. |",
        "| `limit_deg` | number or null | none | The largest wobble. |",
        "| `tilt_deg` | number or null; ≥ -90, ≤ 90 | none | The cradle's tilt, when it has one. |",
    ]
    assert "### `px4`" in out  # the built-ins beside it
    still = out.split("### `still`\n", 1)[1].split("\n### ", 1)[0]
    assert "Takes no options: any key under its `options` is an error." in still and "| option |" not in still


def test_the_docs_page_holds_magline_s_own_plugins_only(wobbler):
    assert "wobbler" not in options_reference(load_plugins(), {"magline"})
