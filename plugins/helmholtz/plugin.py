"""Registers the ``helmholtz`` field source and takes over acquisition and fit on coil stations.

The acquire and fit hooks answer only when the station's field source is the coil (or the samples carry the
applied field); otherwise they return ``None`` and the core's tumble acquisition and ellipsoid fit run as
usual.  What they do is in :mod:`magline.plugins.helmholtz.phases`, imported on a unit's first use: every
command loads this plugin, and the coil's arithmetic needs NumPy.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from magline.plugin import hookimpl

if TYPE_CHECKING:
    from magline.plugin import Acquisition, FitOptions, FitResult, RawSamples, RunContext
    from magline.plugins.helmholtz.options import HelmholtzOptions
    from magline.plugins.helmholtz.source import HelmholtzField


@hookimpl
def magline_register_field_sources(register):
    register("helmholtz", create_helmholtz_field, options="magline.plugins.helmholtz.options:HelmholtzOptions")


def create_helmholtz_field(station: Any, options: HelmholtzOptions) -> HelmholtzField:
    """The coil as the station's field source (its NumPy imported when a station has one)."""
    from magline.plugins.helmholtz.source import HelmholtzField

    return HelmholtzField(options)


@hookimpl
def magline_acquire(run: RunContext, attempt: int) -> Acquisition | None:
    """Step the coil through its schedule, reading the unit at each applied vector (:func:`phases.acquire
    <magline.plugins.helmholtz.phases.acquire>`); ``None`` on a station whose field source is not the coil."""
    from magline.plugins.helmholtz.phases import acquire

    return acquire(run, attempt)


@hookimpl
def magline_fit(run: RunContext, samples: RawSamples, options: FitOptions) -> FitResult | None:
    """The affine fit to the applied vectors, when the samples carry them; else ``None``."""
    from magline.plugins.helmholtz.phases import fit

    return fit(run, samples, options)


@hookimpl
def magline_validate(run: RunContext, fit: FitResult) -> list | None:
    """The coil frame's misalignment, for an affine fit."""
    from magline.plugins.helmholtz.phases import validate

    return validate(run, fit)
