"""How well a fit knows the calibrated field's magnitude in one direction.

Why: after the power cycle the station reads the firmware's calibrated field in whatever attitude the
unit rests and holds its magnitude against the reference.  A tumble stopped once the calibration is
determined (coverage ≈ 0.6) leaves directions the fit saw little of; there the calibrated magnitude
is known less well than on the readings' sphere, and a good unit read 3 % off in one and FAILed
(issue 50).  The tolerance there is widened by this σ — the fit's own, from its parameter covariance
— instead of by a guess.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from magline.core.fit import model as mdl


@dataclass(frozen=True)
class RadialUncertainty:
    """The fit's parameters and covariance as the radial σ needs them (normalised units, see
    :mod:`magline.core.fit.model`; drift terms left out: the end state is what is written)."""

    layout: mdl.Layout
    p: NDArray
    cov: NDArray  # of the offset and soft-iron parameters
    centre: NDArray
    scale: float
    field_ut: float

    def sigma_ut(self, raw_ut: NDArray) -> NDArray:
        """1σ of ``|S·(m − h)|`` (µT) at each raw reading (rows), by first-order propagation."""
        x = (np.atleast_2d(np.asarray(raw_ut, float)) - self.centre) / self.scale
        core = 3 + self.layout.n_soft
        p = self.p.copy()
        base = mdl.radial(self.layout, p, x, None)
        step = 1e-6
        jac = np.empty((core, len(x)))
        for k in range(core):
            moved = p.copy()
            moved[k] += step
            jac[k] = (mdl.radial(self.layout, moved, x, None) - base) / step
        variance = np.einsum("in,ij,jn->n", jac, self.cov, jac)
        return self.field_ut * np.sqrt(np.clip(variance, 0.0, None))
