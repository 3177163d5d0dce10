"""The model's analytic derivatives against central finite differences.

Why: the fit's steps, its covariance, the Cramér–Rao bound in the benchmark and the heading
uncertainty all rest on these Jacobians; a wrong entry would not crash anything, it would quietly
make the fit slower and the reported σ wrong.
"""

from __future__ import annotations

import numpy as np
import pytest

from magline.core.fit import model as mdl

STEP = 1e-6
# central differences of smooth functions of order one: truncation O(STEP²), rounding O(1e-16/STEP)
TOLERANCE = 1e-8


def point(rng, layout: mdl.Layout):
    """A soft iron with axis ratio up to ~1.3, an offset, drift, and samples around the ellipsoid."""
    a = rng.normal(scale=0.1, size=(3, 3))
    s = np.eye(3) + 0.5 * (a + a.T)
    p = mdl.pack(layout, rng.normal(scale=0.3, size=3), s, rng.normal(scale=0.05, size=3))
    x = rng.normal(size=(40, 3))
    tau = rng.uniform(-1.0, 0.0, size=40) if layout.drift else None
    return p, x, tau


def central_difference(f, p):
    cols = []
    for k in range(len(p)):
        e = np.zeros(len(p))
        e[k] = STEP
        cols.append((f(p + e) - f(p - e)) / (2 * STEP))
    return np.stack(cols, axis=1)


LAYOUTS = [mdl.Layout(model, drift) for model in ("full", "diagonal", "sphere") for drift in (False, True)]


@pytest.mark.parametrize("layout", LAYOUTS, ids=lambda lay: f"{lay.model}{'+drift' if lay.drift else ''}")
def test_radial_jacobian_matches_finite_differences(rng, layout):
    p, x, tau = point(rng, layout)
    rho, jac = mdl.radial_jacobian(layout, p, x, tau)
    assert np.allclose(rho, mdl.radial(layout, p, x, tau))
    numeric = central_difference(lambda q: mdl.radial(layout, q, x, tau), p)
    assert np.max(np.abs(jac - numeric)) < TOLERANCE


@pytest.mark.parametrize("layout", LAYOUTS, ids=lambda lay: f"{lay.model}{'+drift' if lay.drift else ''}")
def test_direction_jacobian_matches_finite_differences(rng, layout):
    p, x, _ = point(rng, layout)
    u, du = mdl.direction_jacobian(layout, p, x)
    assert np.allclose(np.linalg.norm(u, axis=0), 1.0)
    core = 3 + layout.n_soft  # drift does not move the end-state direction: no row for it

    def directions(q):
        full = p.copy()
        full[:core] = q
        return mdl.direction_jacobian(layout, full, x)[0].ravel()

    numeric = central_difference(directions, p[:core]).reshape(3, len(x), core)
    assert du.shape == (core, 3, len(x))
    assert np.max(np.abs(du - numeric.transpose(2, 0, 1))) < TOLERANCE


def test_log_gain_gradient_matches_finite_differences(rng):
    for model in ("full", "diagonal", "sphere"):
        layout = mdl.Layout(model, drift=False)
        p, _, _ = point(rng, layout)
        numeric = central_difference(lambda q, lay=layout: np.array([mdl.log_raw_radius(lay, q)]), p)[0]
        assert np.max(np.abs(mdl.log_gain_gradient(layout, p) - numeric)) < TOLERANCE


@pytest.mark.parametrize("layout", LAYOUTS, ids=lambda lay: f"{lay.model}{'+drift' if lay.drift else ''}")
def test_radial_gradient_is_the_derivative_along_the_sample(rng, layout):
    p, x, tau = point(rng, layout)
    rho, grad = mdl.radial_gradient(layout, p, x, tau)
    assert np.allclose(rho, mdl.radial(layout, p, x, tau))
    for axis in range(3):
        e = np.zeros(3)
        e[axis] = STEP
        numeric = (mdl.radial(layout, p, x + e, tau) - mdl.radial(layout, p, x - e, tau)) / (2 * STEP)
        assert np.max(np.abs(grad[axis] - numeric)) < TOLERANCE
    assert np.allclose(mdl.gradient_norm(layout, p, x, tau), np.linalg.norm(grad, axis=0))
