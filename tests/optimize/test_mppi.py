"""Tests of the static MPPI update :class:`uuv_ocp.optimize.mppi.PathIntegral` (``method="mppi"``).

The registry-wide tests of ``test_optimisers.py`` (quality, seeding, budget, history, bad
options) run on ``mppi`` too; these check the update against its analytic limit.
"""

from __future__ import annotations

import numpy as np
import pytest

from uuv_ocp.optimize import PathIntegral, importance_weights, minimize


def test_one_update_is_the_gaussian_posterior_mean():
    # sampling N(μ, σ²I) and weighting by exp(−f/λ) with f = ½(x − c)ᵀA(x − c) is, in the
    # limit of many samples, the mean of N(μ, σ²I)·exp(−f/λ): precision P = I/σ² + A/λ,
    # mean P⁻¹(μ/σ² + A c/λ)
    rng = np.random.default_rng(3)
    dim, sigma, lam = 3, 1.0, 2.0
    a = np.array([[2.0, 0.5, 0.0], [0.5, 1.0, 0.3], [0.0, 0.3, 3.0]])
    c = np.array([1.0, -0.5, 0.3])
    mu = np.array([0.2, 0.1, -0.4])
    lower, upper = -20.0 * np.ones(dim), 20.0 * np.ones(dim)  # σ = noise · width = 1, no clipping
    algorithm = PathIntegral(
        lower,
        upper,
        400_000,
        1,
        {"noise": sigma / 40.0, "final_noise": sigma / 40.0, "temperature": lam, "scale": "none"},
    )
    algorithm.mean = mu.copy()
    cloud = algorithm.propose(0, rng)
    d = cloud - c
    costs = 0.5 * np.einsum("ij,jk,ik->i", d, a, d)
    algorithm.accept(cloud, costs)
    precision = np.eye(dim) / sigma**2 + a / lam
    expected = np.linalg.solve(precision, mu / sigma**2 + a @ c / lam)
    assert np.max(np.abs(algorithm.mean - expected)) < 0.01  # Monte Carlo error ~2e-3 here
    assert np.max(np.abs(mu - expected)) > 0.3  # the update moved: the check is not vacuous


def test_weights_are_the_softmax_and_drop_non_finite_costs():
    values = np.array([3.0, 1.0, np.nan, 2.0, np.inf])
    weights = importance_weights(values, 0.5)
    finite = np.exp(-np.array([3.0, 1.0, 2.0]) / 0.5)
    assert np.allclose(weights[[0, 1, 3]], finite / finite.sum(), rtol=0, atol=1e-15)
    assert weights[2] == weights[4] == 0.0
    assert np.allclose(importance_weights(np.full(4, np.nan), 1.0), 0.25)


def test_mean_and_every_sample_hold_the_box():
    # the unconstrained minimum lies outside the box: clipped samples, a convex-combination mean
    lower, upper = np.array([-1.0, 0.0]), np.array([1.0, 2.0])
    seen = []

    def fun(x):
        seen.append(x.copy())
        return np.sum((x - np.array([5.0, -3.0])) ** 2, axis=1)

    result = minimize(fun, lower, upper, "mppi", population=16, iterations=30, seed=5)
    every = np.vstack(seen)
    assert np.all(every >= lower) and np.all(every <= upper)
    assert np.allclose(result.x, [1.0, 0.0], atol=1e-2)


def test_noise_shrinks_from_noise_to_final_noise_over_the_budget():
    lower, upper = np.zeros(2), np.array([1.0, 4.0])
    algorithm = PathIntegral(lower, upper, 5, 11, {"noise": 0.4, "final_noise": 0.004})
    assert np.allclose(algorithm.noise_at(0), [0.4, 1.6])
    assert np.allclose(algorithm.noise_at(10), [0.004, 0.016])
    assert np.allclose(algorithm.noise_at(5), np.sqrt(0.4 * 0.004) * np.array([1.0, 4.0]))


def test_relative_temperature_makes_the_search_unit_free():
    # scale="median": multiplying the objective by 1000 changes nothing but the reported cost
    lower, upper = -3.0 * np.ones(4), 3.0 * np.ones(4)

    def fun(x):
        return np.sum((x - 0.7) ** 2, axis=1)

    small = minimize(fun, lower, upper, "mppi", iterations=20, seed=8)
    large = minimize(lambda x: 1000.0 * fun(x), lower, upper, "mppi", iterations=20, seed=8)
    assert np.allclose(small.x, large.x, rtol=0, atol=1e-12)


def test_temperature_stays_unit_free_when_half_the_cloud_ties_at_the_best_cost():
    # a plateau (most of the cloud at the minimum): λ from the full spread, so scaled costs
    # give scaled λ and the same weights; only an all-equal cloud falls back to λ = temperature
    algorithm = PathIntegral(np.zeros(2), np.ones(2), 5, 3, {"temperature": 0.5})
    costs = np.array([2.0, 2.0, 2.0, 3.0, 6.0])
    assert algorithm.temperature(costs) == pytest.approx(0.5 * 4.0)
    assert algorithm.temperature(1000.0 * costs) == pytest.approx(1000.0 * algorithm.temperature(costs))
    assert algorithm.temperature(np.full(5, 7.0)) == pytest.approx(0.5)


@pytest.mark.parametrize(
    ("options", "name"),
    [
        ({"noise": 0.0}, "noise"),
        ({"temperature": -1.0}, "temperature"),
        ({"final_noise": 0.5, "noise": 0.1}, "final_noise"),
        ({"scale": "mad"}, "scale"),
    ],
)
def test_bad_options_raise_naming_the_option(options, name):
    with pytest.raises(ValueError, match=name):
        minimize(lambda x: np.sum(x**2, axis=1), -np.ones(2), np.ones(2), "mppi", options=options)
