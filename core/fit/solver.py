"""One Levenberg–Marquardt entry point for every least-squares fit in ``magline.core.fit``.

Why a wrapper: scipy/MINPACK asks for residuals and Jacobian in separate calls, often twice at the
same point, and most of its calls are residual-only trial steps.  The objectives here can give
residuals alone (cheap) or both in one pass (sharing the calibrated vectors); this wrapper asks for
exactly what MINPACK needs and never evaluates the same point twice.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from numpy.typing import NDArray

# Steps (in normalised parameters, of order one) below this end Gauss–Newton: the parameters' 1σ is
# about 1e-3 for a 600-sample tumble and 1e-4 for 100 000 samples, so the solution is then known to
# 1e-4σ or better, far below the O(σ²) bias the bootstrap measures.
SETTLED_STEP = 1e-8

# objective(p, with_jacobian) -> (residuals, Jacobian or None)
Objective = Callable[[NDArray, bool], tuple[NDArray, NDArray | None]]


class _PointCache:
    """The last point's residuals (and Jacobian, once asked for)."""

    def __init__(self, objective: Objective) -> None:
        self.objective = objective
        self.point: NDArray | None = None
        self.r: NDArray | None = None
        self.jac: NDArray | None = None

    def _at(self, q: NDArray) -> bool:
        return self.point is not None and np.array_equal(q, self.point)

    def residuals(self, q: NDArray) -> NDArray:
        if not self._at(q):
            self.point, self.jac = np.array(q, copy=True), None
            self.r, _ = self.objective(q, False)
        assert self.r is not None
        return self.r

    def jacobian(self, q: NDArray) -> NDArray:
        if not self._at(q) or self.jac is None:
            self.point = np.array(q, copy=True)
            self.r, self.jac = self.objective(q, True)
        assert self.jac is not None
        return self.jac


def levenberg_marquardt(objective: Objective, p0: NDArray, tol: float) -> NDArray:
    """Minimise ‖r(p)‖² from ``p0`` with MINPACK's LM (``xtol = ftol = gtol = tol``)."""
    cache = _PointCache(objective)
    # leastsq is the thin MINPACK binding (least_squares(method="lm") wraps the same lmder with
    # more set-up per call, which is most of the cost of a 600-sample refit)
    # full_output: a run that stops on its evaluation budget is judged by the caller's own checks
    # (divergence, refusal), not reported as a warning
    # diag = 1: fixed, unit variable scaling (least_squares' default for "lm"); MINPACK's own
    # Jacobian-based scaling lets a start with outliers run off to a degenerate ellipsoid
    from scipy import optimize  # imported on use: scipy's optimisers cost most of a CLI start that never fits

    p, *_ = optimize.leastsq(cache.residuals, p0, Dfun=cache.jacobian, xtol=tol, ftol=tol, gtol=tol,
                             diag=np.ones(len(p0)), full_output=True)
    return np.asarray(p, dtype=float)


def gauss_newton(objective: Objective, p0: NDArray, step_tol: float = SETTLED_STEP,
                 max_steps: int = 8) -> NDArray | None:
    """Gauss–Newton from a start already near the minimum, or None when it does not settle.

    Why: a bootstrap refit starts within O(σ) of its solution, where the problem is linear to far
    below the noise and each step costs one evaluation and a 12×12 solve; MINPACK's trust-region
    bookkeeping costs more than that.  When a step fails to reduce the cost before settling (a
    strongly non-linear refit), the caller falls back to :func:`levenberg_marquardt`.
    """
    p = np.asarray(p0, dtype=float)
    r, jac = objective(p, True)
    cost = float(r @ r)
    for _ in range(max_steps):
        assert jac is not None
        try:
            step = np.linalg.solve(jac.T @ jac, jac.T @ r)
        except np.linalg.LinAlgError:
            return None
        small = float(np.max(np.abs(step))) <= step_tol
        # a step this small is the last: only its cost is needed, not another Jacobian
        r_t, jac_t = objective(p - step, not small)
        cost_t = float(r_t @ r_t)
        if not np.isfinite(cost_t) or cost_t > cost:
            return p if small else None  # settled to rounding, or not converging
        if small:
            return p - step
        p, r, jac, cost = p - step, r_t, jac_t, cost_t
    return None
