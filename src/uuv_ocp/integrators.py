"""Explicit Runge–Kutta discretisation of continuous dynamics as CasADi Functions."""

from __future__ import annotations

import casadi as ca

from uuv_ocp import _validation as check


def rk4_step(dynamics: ca.Function, dt: float, substeps: int = 1, name: str = "rk4") -> ca.Function:
    """Classical fourth-order Runge–Kutta map over one interval of length ``dt``.

    Parameters
    ----------
    dynamics : casadi.Function
        ``f(x, u, ...) -> xdot``; every input after the first is held constant on the interval.
    dt : float
        Interval length (s), > 0.
    substeps : int
        Number of equal RK4 steps inside the interval, >= 1.
    name : str
        Name of the returned Function.

    Returns
    -------
    casadi.Function
        ``F(x, u, ...) -> x_next`` with the same inputs as ``dynamics``; the local error per
        interval is O(h⁵) with ``h = dt / substeps``.
    """
    dt = check.positive_float("dt", dt)
    substeps = check.positive_int("substeps", substeps)
    inputs = [ca.SX.sym(dynamics.name_in(i), dynamics.sparsity_in(i)) for i in range(dynamics.n_in())]
    state, held = inputs[0], inputs[1:]
    step = dt / substeps
    for _ in range(substeps):
        k1 = dynamics(state, *held)
        k2 = dynamics(state + step / 2 * k1, *held)
        k3 = dynamics(state + step / 2 * k2, *held)
        k4 = dynamics(state + step * k3, *held)
        state = state + step / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    return ca.Function(
        name,
        inputs,
        [state],
        [dynamics.name_in(i) for i in range(dynamics.n_in())],
        ["x_next"],
    )
