"""The least-squares entry points the fit and its bootstrap use."""

from __future__ import annotations

import numpy as np

from magline.core.fit.solver import gauss_newton, levenberg_marquardt


def linear_problem(rng):
    a = rng.normal(size=(50, 4))
    b = a @ np.array([1.0, -2.0, 0.5, 3.0]) + rng.normal(scale=0.01, size=50)

    def objective(q, with_jacobian):
        return a @ q - b, (a if with_jacobian else None)

    return objective, np.linalg.lstsq(a, b, rcond=None)[0]


def rosenbrock(q, with_jacobian):
    r = np.array([10.0 * (q[1] - q[0] ** 2), 1.0 - q[0]])
    jac = np.array([[-20.0 * q[0], 10.0], [-1.0, 0.0]]) if with_jacobian else None
    return r, jac


def test_gauss_newton_reaches_the_least_squares_solution(rng):
    objective, solution = linear_problem(rng)
    assert np.allclose(gauss_newton(objective, np.zeros(4), 1e-12), solution, atol=1e-10)


def test_gauss_newton_gives_up_where_a_step_does_not_help_and_lm_then_solves_it():
    start = np.array([-1.2, 1.0])
    assert gauss_newton(rosenbrock, start, 1e-12, max_steps=2) is None
    assert np.allclose(levenberg_marquardt(rosenbrock, start, 1e-12), [1.0, 1.0], atol=1e-8)


def test_levenberg_marquardt_evaluates_each_point_once_and_jacobians_only_when_asked(rng):
    objective, solution = linear_problem(rng)
    seen: list[tuple[tuple[float, ...], bool]] = []

    def counting(q, with_jacobian):
        seen.append((tuple(q), with_jacobian))
        return objective(q, with_jacobian)

    assert np.allclose(levenberg_marquardt(counting, np.zeros(4), 1e-12), solution, atol=1e-8)
    assert len(seen) == len(set(seen))  # no point evaluated twice in the same way
    assert any(not jac for _, jac in seen)  # trial points got residuals only
