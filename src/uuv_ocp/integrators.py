"""Explicit Runge–Kutta discretisation of continuous dynamics as CasADi Functions."""

from __future__ import annotations

import casadi as ca

from uuv_ocp import _validation as check
from uuv_ocp._concurrency import serialised


def _rk4_states(dynamics: ca.Function, dt: float, substeps: int) -> tuple[list[ca.SX], list[ca.SX]]:
    """Symbolic inputs of ``dynamics`` and the states after each of ``substeps`` RK4 steps."""
    dt = check.positive_float("dt", dt)
    substeps = check.positive_int("substeps", substeps)
    inputs = [ca.SX.sym(dynamics.name_in(i), dynamics.sparsity_in(i)) for i in range(dynamics.n_in())]
    state, held = inputs[0], inputs[1:]
    step = dt / substeps
    states = []
    for _ in range(substeps):
        k1 = dynamics(state, *held)
        k2 = dynamics(state + step / 2 * k1, *held)
        k3 = dynamics(state + step / 2 * k2, *held)
        k4 = dynamics(state + step * k3, *held)
        state = state + step / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        states.append(state)
    return inputs, states


@serialised
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
    inputs, states = _rk4_states(dynamics, dt, substeps)
    return ca.Function(
        name,
        inputs,
        [states[-1]],
        [dynamics.name_in(i) for i in range(dynamics.n_in())],
        ["x_next"],
    )


@serialised
def rk4_path(dynamics: ca.Function, dt: float, substeps: int = 1, name: str = "rk4_path") -> ca.Function:
    """Map ``x`` to the states after every sub-step of :func:`rk4_step` (same arithmetic, numbers).

    Parameters
    ----------
    dynamics, dt, substeps, name
        As :func:`rk4_step`.

    Returns
    -------
    casadi.Function
        ``F(x, u, ...) -> path`` with ``path`` of shape ``(nx, substeps)``: column ``j`` is the
        state at ``(j + 1) dt / substeps``; the last column equals ``rk4_step``'s ``x_next``.
        A closed loop records the plant between control instants with it (collision checks).
    """
    inputs, states = _rk4_states(dynamics, dt, substeps)
    return ca.Function(
        name,
        inputs,
        [ca.horzcat(*states)],
        [dynamics.name_in(i) for i in range(dynamics.n_in())],
        ["path"],
    )
