"""Registers the ``gimbal`` motion (``motion: {type: gimbal, options: {resource: …}}``)."""

from __future__ import annotations

from magline.plugin import hookimpl


@hookimpl
def magline_register_motions(register):
    # named by place: the rig's module is imported when a station file uses it
    register("gimbal", "magline.plugins.gimbal.motion:create_gimbal_motion",
             options="magline.plugins.gimbal.motion:GimbalOptions")
