"""Process capability against the station's limits: Cpk (within-process σ) and Ppk (overall σ),
with confidence intervals — so that limits can be tightened once the process is known.

* Cpk = min(USL − μ, μ − LSL) / 3σ_within, σ_within = MR̄ / d₂ (the I-MR chart's);
* Ppk = the same with the overall sample standard deviation;
* a one-sided limit gives the one-sided index (CPU or CPL): a bounded figure (an angle ≥ 0, a
  fraction) with only its upper limit is judged against that limit alone;
* confidence interval: Bissell's normal approximation (1990),
  Ĉ ± z₁₋α/₂ · √(1/(9n) + Ĉ²/(2ν)), ν = n − 1 for Ppk and 0.62 (n − 1) for Cpk, whose σ from the
  moving ranges is worth fewer degrees of freedom (Cryer & Ryan, 1990).

Those formulas hold for a normal characteristic.  Which shape applies is tested first
(Anderson–Darling, :mod:`.normality`), then, as ISO 22514-2 / -4 allow (Minitab's non-normal
capability does the same):

1. normal (p ≥ 0.05): the normal indices above;
2. else, a positive characteristic that a Box-Cox transformation (λ by maximum likelihood,
   ``scipy.stats.boxcox``) makes normal: the normal indices of the transformed values against the
   transformed limits (the transformation is increasing, so the limits keep their order);
3. else the ISO 22514-2 percentile method on the best-fitting shape (3-parameter gamma, log-normal
   or Weibull, Johnson SU, by AIC, as ``scipy.stats`` fits them) among those whose parameters lie inside
   their domain with a margin (:func:`_refusal`: where the likelihood can run away at the threshold, the
   threshold below the minimum by 5 % of the range — 1 % for a log-normal —, a scale above the data's
   resolution, tails within 3 ranges of the data): Ppk = min((USL − X₅₀)/(X₉₉.₈₆₅
   − X₅₀), (X₅₀ − LSL)/(X₅₀ − X₀.₁₃₅)), an overall index only (there is no within-process σ of a fitted
   shape) and no interval;
4. else no capability figure, with the reason (never 0.00).

Box-Cox's λ is bounded to [−5, 5].

The method is always said with the index.  Written here because no maintained Python library
computes the indices; the normal quantile is the standard library's ``statistics.NormalDist``,
scipy.stats is imported only where the shape is not normal.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from statistics import NormalDist

import numpy as np

from magline.core.quality.charts import D2  # the within σ of a transformed characteristic: MR̄ / d₂
from magline.core.quality.normality import Normality, anderson_darling


@dataclass(frozen=True)
class Index:
    value: float
    low: float | None  # confidence interval (None: the method gives none)
    high: float | None

    def words(self) -> str:
        return f"{self.value:.2f}" if self.low is None or self.high is None else \
            f"{self.value:.2f} [{self.low:.2f}, {self.high:.2f}]"


def index_words(index: Index | None) -> str:
    """An index with its interval as the tables print it; "—" where none is stated."""
    return "—" if index is None else index.words()


@dataclass(frozen=True)
class Capability:
    n: int
    mean: float
    sigma_within: float
    sigma_overall: float
    cpk: Index | None
    ppk: Index | None
    method: str = "normal"  # "normal", "box-cox" or "percentile"
    method_words: str = "normal"  # the method as the report says it, with its figures
    normality: Normality | None = None  # the Anderson–Darling test on the values (None below 8 values)
    box_cox_lambda: float | None = None
    transformed: tuple[float, float] | None = None  # Box-Cox: mean and σ of the transformed values
    shape: object | None = None  # the percentile method's fitted scipy distribution (the report draws it)

    @property
    def method_short(self) -> str:
        if self.method == "box-cox":
            return f"Box-Cox λ {self.box_cox_lambda:.2f}"
        return "ISO percentile" if self.method == "percentile" else "normal"

    def to_dict(self) -> dict:
        def index(i: Index | None) -> dict | None:
            return None if i is None else {"value": i.value, "low": i.low, "high": i.high}

        return {"n": self.n, "mean": self.mean, "sigma_within": self.sigma_within,
                "sigma_overall": self.sigma_overall, "cpk": index(self.cpk), "ppk": index(self.ppk),
                "method": self.method, "method_words": self.method_words, "box_cox_lambda": self.box_cox_lambda,
                "normality": None if self.normality is None else self.normality.to_dict()}


# Fewer judged units than this and no capability is stated: AIAG's SPC manual (2nd ed.) asks 25 subgroups
# before limits are computed at all; a Cpk from three units (once printed as 1388 [27.8, 2750]) is noise.
MIN_UNITS = 25
MIN_UNITS_SOURCE = "AIAG SPC manual: 25 subgroups"


# How many degrees of freedom a σ from the mean moving range (MR̄ / d₂) is worth, per unit: about 0.62
# of the sample standard deviation's (Cryer & Ryan, 1990).  Bissell's interval with n − 1 for a Cpk held
# its true value only 87–89 % of the time at 95 % (benchmarks/capability_study.py); with these it holds
# it as often as Ppk's.
MR_DF_PER_UNIT = 0.62


def _index(mean: float, sigma: float, low: float | None, high: float | None, n: int,
           confidence: float, min_units: int, within: bool = False) -> Index | None:
    """The index against the limits given, with Bissell's interval; ``within``: σ is MR̄ / d₂ (a Cpk),
    whose fewer degrees of freedom widen the interval."""
    if sigma <= 0 or n < max(min_units, 2) or (low is None and high is None):
        return None
    sides = [(high - mean) / (3 * sigma)] if high is not None else []
    sides += [(mean - low) / (3 * sigma)] if low is not None else []
    value = min(sides)
    z = NormalDist().inv_cdf(0.5 + confidence / 2)
    df = MR_DF_PER_UNIT * (n - 1) if within else n - 1
    half = z * math.sqrt(1 / (9 * n) + value ** 2 / (2 * df))
    return Index(value, value - half, value + half)


def capability(values: np.ndarray, low: float | None, high: float | None, sigma_within: float,
               confidence: float = 0.95, min_units: int = MIN_UNITS) -> Capability:
    """Cpk / Ppk with their intervals by the method the shape allows (see the module); None for an
    index below ``min_units`` values (see MIN_UNITS) or without a limit."""
    x = np.asarray(values, dtype=float)
    x = x[np.isfinite(x)]
    mean = float(x.mean()) if x.size else math.nan
    overall = float(x.std(ddof=1)) if x.size > 1 else 0.0
    normality = anderson_darling(x)
    normal = Capability(n=int(x.size), mean=mean, sigma_within=sigma_within, sigma_overall=overall,
                        cpk=_index(mean, sigma_within, low, high, x.size, confidence, min_units, within=True),
                        ppk=_index(mean, overall, low, high, x.size, confidence, min_units),
                        method_words="normal" + (f" (Anderson–Darling p {normality.p_words})" if normality else ""),
                        normality=normality)
    if normality is None or normality.normal or normal.ppk is None:
        return normal
    return _box_cox(x, low, high, normal, confidence, min_units) or _percentile(x, low, high, normal)


def _box_cox(x: np.ndarray, low: float | None, high: float | None, normal: Capability, confidence: float,
             min_units: int) -> Capability | None:
    """The normal indices of Box-Cox-transformed values, where the transformation makes them normal."""
    from scipy import special, stats

    if np.any(x <= 0) or (high is not None and high <= 0):
        return None
    lam = bounded_box_cox_lambda(x)
    y = stats.boxcox(x, lam)
    shape = anderson_darling(y)
    if shape is None or not shape.normal:
        return None
    t_low = None if low is None or low <= 0 else float(special.boxcox(low, lam))  # ≤ 0: no value reaches it
    t_high = None if high is None else float(special.boxcox(high, lam))
    if t_low is None and t_high is None:
        return None
    mean, overall = float(y.mean()), float(y.std(ddof=1))
    within = float(np.abs(np.diff(y)).mean()) / D2
    cpk = _index(mean, within, t_low, t_high, y.size, confidence, min_units, within=True)
    ppk = _index(mean, overall, t_low, t_high, y.size, confidence, min_units)
    if cpk is not None and ppk is not None:
        cpk, ppk = _with_lambda_uncertainty(cpk, ppk, y.size, mean, overall, float(lam), low, high, confidence)
    return Capability(n=normal.n, mean=normal.mean, sigma_within=normal.sigma_within,
                      sigma_overall=normal.sigma_overall, cpk=cpk, ppk=ppk, method="box-cox",
                      box_cox_lambda=float(lam), transformed=(mean, overall),
                      method_words=(f"Box-Cox λ = {lam:.2f} (not normal: Anderson–Darling p {normal.normality.p_words}"
                                    f"; transformed: p {shape.p_words})"), normality=normal.normality)


# Box-Cox's λ is sought within these bounds (Minitab's own).  Why bounded: on 30 values all within
# 0.28–0.32 against an upper limit of 1.0 the unbounded maximum likelihood went to λ = −11.6, where the
# transformed limit crowds the data, and stated Ppk 1.01 for a characteristic with room for 20σ.
LAMBDA_BOUNDS = (-5.0, 5.0)


def bounded_box_cox_lambda(x: np.ndarray) -> float:
    """The maximum-likelihood Box-Cox λ within :data:`LAMBDA_BOUNDS` (``scipy.stats.boxcox_llf``)."""
    from scipy import optimize, stats

    found = optimize.minimize_scalar(lambda lam: -stats.boxcox_llf(lam, x), bounds=LAMBDA_BOUNDS, method="bounded",
                                     options={"xatol": 1e-6})
    return float(found.x)


# The Box-Cox intervals come from a parametric bootstrap of the whole procedure: this many data sets drawn
# from the fitted model (normal after the transformation), each transformed with its own λ by maximum
# likelihood and its indices computed as the data's were.  Why: Bissell's interval on the transformed
# values takes λ as known, and held a log-normal characteristic's true Ppk only 73–82 % of the time at
# 95 % (benchmarks/capability_study.py); λ's own uncertainty is most of what it missed.  Seeded: a report
# reprinted from the same units states the same interval.
BOOTSTRAP_SETS = 200
BOOTSTRAP_SEED = 22514
# Data sets of more values are drawn at this size and the interval's half-widths scaled by √(size / n):
# each λ fit is an optimiser's run, and spc charts 10,000 units inside its 3 s.
BOOTSTRAP_VALUES = 1000


LAMBDA_REACH, LAMBDA_STEP = 2.5, 0.05  # the grid about the data's own λ that each data set's λ is sought on


def box_cox_lambdas(sets: np.ndarray, around: float) -> np.ndarray:
    """The maximum-likelihood Box-Cox λ of each row of ``sets`` (positive values), as ``scipy.stats.boxcox``
    finds it one row at a time.  Why not that: 200 rows took 1.4 s of every Box-Cox characteristic's
    capability, and ``spc`` has 3 s for all of them.  Here the profile log-likelihood
    ``(λ − 1)·Σ ln x − n/2 · ln var(y_λ)`` (scipy's ``boxcox_llf``) is evaluated for every row at once on a
    grid about ``around`` and its maximum placed by the parabola through the best three points; a row
    whose maximum lies at the grid's edge is left to scipy."""
    from scipy import stats

    logs = np.log(sets)
    total = logs.sum(axis=1)
    grid = around + np.arange(-LAMBDA_REACH, LAMBDA_REACH + LAMBDA_STEP / 2, LAMBDA_STEP)

    def profile(lam: float) -> np.ndarray:
        y = logs if abs(lam) < 1e-12 else np.expm1(lam * logs) / lam
        return (lam - 1.0) * total - 0.5 * sets.shape[1] * np.log(y.var(axis=1))

    table = np.array([profile(float(lam)) for lam in grid])  # grid × rows
    best = table.argmax(axis=0)
    rows = np.arange(sets.shape[0])
    inside = (best > 0) & (best < grid.size - 1)
    k = np.clip(best, 1, grid.size - 2)
    f0, f1, f2 = table[k - 1, rows], table[k, rows], table[k + 1, rows]
    bend = f0 - 2.0 * f1 + f2
    shift = np.where(bend < 0, 0.5 * (f0 - f2) / np.where(bend < 0, bend, -1.0), 0.0)
    found = grid[k] + LAMBDA_STEP * np.clip(shift, -1.0, 1.0)
    for row in np.flatnonzero(~inside):
        found[row] = stats.boxcox(sets[row])[1]
    return found


def _with_lambda_uncertainty(cpk: Index, ppk: Index, n: int, mean: float, sd: float, lam: float,
                             low: float | None, high: float | None, confidence: float) -> tuple[Index, Index]:
    """Cpk and Ppk with intervals that include λ's uncertainty (see BOOTSTRAP_SETS): the bootstrap
    indices' spread below and above their median, laid about the data's own index.  (The basic
    interval, 2Ĉ minus the quantiles, held the log-normal's true Ppk 88–91 % of the time at 95 %;
    this one 93–96 %.)"""
    from scipy import special

    size = min(n, BOOTSTRAP_VALUES)
    rng = np.random.default_rng(BOOTSTRAP_SEED)
    draws = special.inv_boxcox(rng.normal(mean, sd, size=(BOOTSTRAP_SETS, size)), lam)
    draws = draws[np.all(np.isfinite(draws) & (draws > 0), axis=1)]  # a set beyond the transformation's range:
    indices = []  # no data set of the model gives it
    for x, lam_b in zip(draws, box_cox_lambdas(draws, lam), strict=True):
        y = special.boxcox(x, lam_b)
        t_low = None if low is None or low <= 0 else float(special.boxcox(low, lam_b))
        t_high = None if high is None else float(special.boxcox(high, lam_b))
        within = float(np.abs(np.diff(y)).mean()) / D2
        c = _index(float(y.mean()), within, t_low, t_high, size, confidence, 2, within=True)
        p = _index(float(y.mean()), float(y.std(ddof=1)), t_low, t_high, size, confidence, 2)
        if c is not None and p is not None:
            indices.append((c.value, p.value))
    if len(indices) < BOOTSTRAP_SETS // 2:
        return cpk, ppk  # the model rarely gives valid data: keep the interval that takes λ as known
    found = np.array(indices)
    tail = (1.0 - confidence) / 2.0
    scale = math.sqrt(size / n)

    def interval(index: Index, column: np.ndarray) -> Index:
        q_low, q_high = np.quantile(column, [tail, 1.0 - tail])
        centre = float(np.median(column))
        return Index(index.value, index.value - (centre - q_low) * scale, index.value + (q_high - centre) * scale)

    return interval(cpk, found[:, 0]), interval(ppk, found[:, 1])


# The shapes the percentile method may fit, as Minitab's distribution identification offers them: the
# one with the lowest AIC describes the characteristic (a tail the data never reach is the fitted
# shape's, so the family matters — a Johnson SU alone put a gamma's 99.865 % point 40 % too far out).
# Johnson SB (bounded on both sides) is left out: its fit cost as much as the four others together, and
# the characteristics charted by default are bounded on one side at most (an angle ≥ 0), which the
# three-parameter shapes take through their location.
SHAPES = ("gamma", "lognorm", "weibull_min", "johnsonsu")
SHAPE_NAMES = {"gamma": "3-parameter gamma", "lognorm": "3-parameter log-normal", "weibull_min": "3-parameter Weibull",
               "johnsonsu": "Johnson SU"}


# The shapes are fitted to at most this many of the values, evenly spread over the window: each fit is
# an optimiser's hundreds of likelihood evaluations, and ``spc`` over 10,000 units fits every skewed
# characteristic (8 of them took 2.8 s of a 4.4 s spc, benchmarks/process_quality.py); 2,000 values fix
# a shape's parameters far more closely than the capability's own sampling error.
FIT_VALUES = 2000


# A fitted shape is a description of the data only where its parameters lie inside their domain with a
# margin: a likelihood that runs away — a threshold drawn up to the smallest value (a gamma or Weibull of
# shape < 1 there has an infinite density), a scale shrunk below the data's own resolution (quantised
# values) — is not a fit.  The rules, stated with the index:
# A gamma's or Weibull's density is infinite at its threshold where its shape is below 1, and the
# likelihood then grows without bound as the threshold reaches the smallest value: such a fit must keep
# its threshold this share of the range below the minimum (a log-normal's, whose likelihood runs away
# the same way as its threshold closes in, the smaller share).
THRESHOLD_MARGIN = {"gamma": 0.05, "weibull_min": 0.05, "lognorm": 0.01}
TAIL_RANGES = 3.0  # its 0.135 % and 99.865 % points within this many sample ranges of the sample's extremes


@dataclass(frozen=True)
class ShapeFit:
    name: str
    dist: object | None
    aic: float
    refused: str = ""  # why the fit is not a shape of the data ("" : it is)


def resolution(x: np.ndarray) -> float:
    """The smallest step between distinct values (the data's quantisation); 0 for fewer than two."""
    steps = np.diff(np.unique(x))
    return float(steps.min()) if steps.size else 0.0


def _refusal(name: str, dist: object, params: tuple, x: np.ndarray) -> str:
    spread = float(x.max() - x.min())
    if spread <= 0:
        return "the values do not vary"
    scale = float(params[-1])
    if scale <= resolution(x):
        return f"its scale {scale:.3g} is below the data's resolution {resolution(x):.3g}"
    runaway = name == "lognorm" or (name in THRESHOLD_MARGIN and float(params[0]) < 1.0)
    margin = THRESHOLD_MARGIN.get(name, 0.0)
    if runaway and float(params[-2]) > x.min() - margin * spread:
        return (f"its threshold {float(params[-2]):.4g} is not below the smallest value {x.min():.4g} by "
                f"{margin:.0%} of the range (shape {float(params[0]):.2f}: its likelihood runs away there)")
    lower, upper = (float(q) for q in dist.ppf([0.00135, 0.99865]))  # type: ignore[attr-defined]
    if not (np.isfinite(lower) and np.isfinite(upper)) or lower < x.min() - TAIL_RANGES * spread \
            or upper > x.max() + TAIL_RANGES * spread:
        return (f"its 0.135 %–99.865 % points ({lower:.4g}, {upper:.4g}) lie beyond {TAIL_RANGES:g} ranges of the "
                "data")
    return ""


def shape_fits(x: np.ndarray) -> list[ShapeFit]:
    """Every candidate shape fitted by maximum likelihood (``scipy.stats``), each with its AIC and, where it
    is not a shape of the data, why (:func:`_refusal`)."""
    import warnings

    from scipy import stats

    if x.size > FIT_VALUES:
        x = x[np.linspace(0, x.size - 1, FIT_VALUES).round().astype(int)]
    out = []
    for name in SHAPES:
        family = getattr(stats, name)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # the optimiser's own complaints; a failed fit is said
            try:
                params = family.fit(x)
                dist = family(*params)
                log_likelihood = float(np.sum(dist.logpdf(x)))
            except (ValueError, RuntimeError, FloatingPointError):
                out.append(ShapeFit(name, None, math.inf, "the fit did not converge"))
                continue
        if not np.isfinite(log_likelihood):
            out.append(ShapeFit(name, None, math.inf, "its likelihood is not finite"))
            continue
        out.append(ShapeFit(name, dist, 2 * len(params) - 2 * log_likelihood, _refusal(name, dist, params, x)))
    return out


def best_shape(x: np.ndarray, fits: list[ShapeFit] | None = None) -> tuple[str, object] | None:
    """(name, frozen scipy distribution) of the accepted shape with the lowest AIC; None if none is."""
    accepted = [f for f in fits or shape_fits(x) if not f.refused]
    best = min(accepted, key=lambda f: f.aic, default=None)
    return None if best is None else (best.name, best.dist)


def _percentile(x: np.ndarray, low: float | None, high: float | None, normal: Capability) -> Capability:
    """ISO 22514-2's percentile Ppk on the best-fitting shape (no Cpk, no interval)."""
    fits = shape_fits(x)
    chosen = best_shape(x, fits)
    tried = "; ".join(f"{SHAPE_NAMES[f.name]} refused: {f.refused}" for f in fits if f.refused)
    if chosen is None:
        return Capability(n=normal.n, mean=normal.mean, sigma_within=normal.sigma_within,
                          sigma_overall=normal.sigma_overall, cpk=None, ppk=None, method="percentile",
                          method_words=f"no capability figure: not normal, not made normal by Box-Cox, and no "
                                       f"shape describes the data ({tried})", normality=normal.normality)
    name, dist = chosen
    lower, median, upper = (float(q) for q in dist.ppf([0.00135, 0.5, 0.99865]))  # type: ignore[attr-defined]
    sides = [(high - median) / (upper - median)] if high is not None and upper > median else []
    sides += [(median - low) / (median - lower)] if low is not None and median > lower else []
    words = (f"ISO 22514-2 percentiles of a fitted {SHAPE_NAMES[name]}, the best of {len(SHAPES)} shapes by AIC "
             f"(not normal: Anderson–Darling p {normal.normality.p_words if normal.normality else '—'}); "
             "Ppk only, no interval" + (f"; {tried}" if tried else ""))
    ppk = Index(min(sides), None, None) if sides and all(map(math.isfinite, sides)) else None
    return Capability(n=normal.n, mean=normal.mean, sigma_within=normal.sigma_within,
                      sigma_overall=normal.sigma_overall, cpk=None, ppk=ppk, method="percentile",
                      method_words=words, normality=normal.normality, shape=dist)
