"""Registers the current sources of the interference sweep: ``electronic-load``."""

from __future__ import annotations

from magline.plugin import hookimpl
from magline.plugins.current.electronic_load import ElectronicLoadOptions, create_electronic_load


@hookimpl
def magline_register_current_sources(register):
    register("electronic-load", create_electronic_load, options=ElectronicLoadOptions)
