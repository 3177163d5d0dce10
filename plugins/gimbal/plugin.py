"""Registers the ``gimbal`` motion (``motion: {type: gimbal, options: {resource: …}}``)."""

from __future__ import annotations

from magline.plugin import hookimpl


@hookimpl
def magline_register_motions(register):
    from magline.plugins.gimbal.motion import GimbalOptions, create_gimbal_motion

    register("gimbal", create_gimbal_motion, options=GimbalOptions)
