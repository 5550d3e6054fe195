"""Standard test functions for :func:`uuv_ocp.minimize`, vectorised over rows (f* = 0).

Each takes ``X`` of shape ``(population, dim)`` and returns ``(population,)`` costs; used by the
tests and by ``benchmarks/bench_swarm_functions.py`` to compare with mealpy.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

Vectorised = Callable[[np.ndarray], np.ndarray]


def sphere(X: np.ndarray) -> np.ndarray:
    """``Σ x²``, minimum 0 at the origin."""
    return np.sum(X * X, axis=1)


def rastrigin(X: np.ndarray) -> np.ndarray:
    """``10 d + Σ (x² − 10 cos 2πx)``, minimum 0 at the origin."""
    return 10.0 * X.shape[1] + np.sum(X * X - 10.0 * np.cos(2.0 * np.pi * X), axis=1)


def rosenbrock(X: np.ndarray) -> np.ndarray:
    """``Σ 100 (x_{i+1} − x_i²)² + (1 − x_i)²``, minimum 0 at (1, …, 1)."""
    return np.sum(100.0 * (X[:, 1:] - X[:, :-1] ** 2) ** 2 + (1.0 - X[:, :-1]) ** 2, axis=1)


def ackley(X: np.ndarray) -> np.ndarray:
    """Ackley's function, minimum 0 at the origin."""
    d = X.shape[1]
    return (
        -20.0 * np.exp(-0.2 * np.sqrt(np.sum(X * X, axis=1) / d))
        - np.exp(np.sum(np.cos(2.0 * np.pi * X), axis=1) / d)
        + 20.0
        + np.e
    )


def shifted(function: Vectorised, centre: np.ndarray | Callable[[int], np.ndarray]) -> Vectorised:
    """``function(X − centre)``: moves the optimum off the origin (``centre`` may depend on dim)."""

    def moved(X: np.ndarray) -> np.ndarray:
        offset = centre(X.shape[1]) if callable(centre) else centre
        return function(X - offset)

    moved.__name__ = f"shifted_{function.__name__}"
    return moved


def griewank(X: np.ndarray) -> np.ndarray:
    """``1 + Σ x²/4000 − Π cos(x_i/√i)``, minimum 0 at the origin."""
    i = np.arange(1, X.shape[1] + 1)
    return 1.0 + np.sum(X * X, axis=1) / 4000.0 - np.prod(np.cos(X / np.sqrt(i)), axis=1)
