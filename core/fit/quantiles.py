"""The quantiles of the F, χ² and Student t distributions the station's statistical tests compare against.

Why not ``scipy.stats``: importing it costs a third of a second of CPU on top of the scipy modules a fit
already loads, paid by every ``magline run`` (its running fit's first drift test waited for it) and every
``magline fit``; the same functions are in ``scipy.special`` (the Cephes library ``scipy.stats`` itself
calls for these distributions), which the fit's optimiser has already imported.
"""

from __future__ import annotations


def f_quantile(probability: float, dfn: float, dfd: float) -> float:
    """The ``probability`` quantile of F(dfn, dfd) (``scipy.stats.f.ppf``)."""
    from scipy.special import fdtri

    return float(fdtri(dfn, dfd, probability))


def chi2_quantile(probability: float, df: float) -> float:
    """The ``probability`` quantile of χ²(df) (``scipy.stats.chi2.ppf``)."""
    from scipy.special import chdtri

    return float(chdtri(df, 1.0 - probability))


def t_quantile(probability: float, df: float) -> float:
    """The ``probability`` quantile of Student's t(df) (``scipy.stats.t.ppf``)."""
    from scipy.special import stdtrit

    return float(stdtrit(df, probability))
