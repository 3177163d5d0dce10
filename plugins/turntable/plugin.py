"""Registers the ``turntable`` motion (``motion: {type: turntable, options: {resource: …}}``)."""

from __future__ import annotations

from magline.plugin import hookimpl


@hookimpl
def magline_register_motions(register):
    from magline.plugins.turntable.motion import TurntableOptions, create_turntable_motion

    register("turntable", create_turntable_motion, options=TurntableOptions)
