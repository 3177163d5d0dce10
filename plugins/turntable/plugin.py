"""Registers the ``turntable`` motion (``motion: {type: turntable, options: {resource: …}}``)."""

from __future__ import annotations

from magline.plugin import hookimpl


@hookimpl
def magline_register_motions(register):
    # named by place: the rig's module is imported when a station file uses it
    register("turntable", "magline.plugins.turntable.motion:create_turntable_motion",
             options="magline.plugins.turntable.motion:TurntableOptions")
