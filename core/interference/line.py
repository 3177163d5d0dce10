"""A straight line through a sweep's readings: the field per amp with its σ.

Its own module because both the analysis of a whole sweep and the sweep itself (deciding, at its top
step, how long to hold it) fit the same line the same way.
"""

from __future__ import annotations

import functools

import numpy as np
from numpy.typing import NDArray

from magline.core.faults import StationFault
from magline.core.fit.quantiles import t_quantile

# The share of slopes whose error 3σ holds for a noise known exactly (a normal's ±3σ): with the noise
# estimated from the sweep's own readings, σ is widened until ±3σ holds the same share (Student's t)
THREE_SIGMA_SHARE = 0.9973


def line_fit(x: NDArray, y: NDArray) -> tuple[NDArray, NDArray, NDArray]:
    """``y ≈ a + c·x`` (rows of ``y`` are vectors): (a, c, σ of c per axis, from the residual scatter
    pooled over the axes).

    Why σ is a little wider than the standard error: the noise is estimated from the same readings, so
    the slope's error over it follows Student's t, whose tails are heavier than a normal's — at the
    defaults' 114 degrees of freedom 0.33 % of slopes fell beyond 3 standard errors, not 0.27 %, and
    fewer readings make it worse.  Every claim the station makes from σ is a 3σ one (how well a written
    slope is known, whether it is worth writing, the benchmark's honesty figure), so σ is the standard
    error times ``t(dof)/3``, with ``t`` the quantile that holds ``THREE_SIGMA_SHARE``: ±3σ then holds
    the truth as often as it would for a known noise."""
    x = np.asarray(x, float)
    y = np.asarray(y, float).reshape(len(x), -1)
    xm = x.mean()
    sxx = float(np.sum((x - xm) ** 2))
    if sxx <= 0 or len(x) < 3:
        raise StationFault("the sweep's current did not change: no slope to fit")
    c = ((x - xm)[:, None] * (y - y.mean(axis=0))).sum(axis=0) / sxx
    a = y.mean(axis=0) - c * xm
    residual = y - a - np.outer(x, c)
    # one noise for every axis of a sensor (pooled: three times the degrees of freedom, so a σ from ten
    # readings a step is not itself a coin toss — with each axis on its own, 0.4–1.5 % of the lengths
    # fell beyond 3σ in the benchmark instead of 0.3 %)
    dof = max(y.shape[1] * (len(x) - 2), 1)
    sigma_res = np.full(y.shape[1], np.sqrt(np.sum(residual**2) / dof))
    return a, c, sigma_res / np.sqrt(sxx) * coverage_widening(dof)


@functools.lru_cache(maxsize=256)
def coverage_widening(dof: int) -> float:
    """How much wider than the standard error σ is for ±3σ to hold ``THREE_SIGMA_SHARE`` of the errors
    when the noise was estimated with ``dof`` degrees of freedom (1.022 at 114, 1.09 at 30)."""
    return t_quantile(0.5 + THREE_SIGMA_SHARE / 2.0, dof) / 3.0


def length_sigma(c: NDArray, sigma: NDArray) -> float:
    """1σ of |c| from the per-axis σ (linearised; near zero, the per-axis σ's RMS)."""
    norm = float(np.linalg.norm(c))
    if norm < 3.0 * float(np.linalg.norm(sigma)):
        return float(np.sqrt(np.mean(sigma**2)))
    return float(np.sqrt(np.sum((c / norm) ** 2 * sigma**2)))
