"""Condensed form of an :class:`~uuv_ocp.ocp.OcpSpec`: cost ``J(U; p)`` by rollout.

The states are a rollout of the **same** integrator Function as the multiple-shooting NLP, so
the condensed objective equals the NLP objective at a feasible point (soft constraints enter
both as the exact L1 penalty ``ρ Σ max(0, violation)``, which the NLP's slacks attain).  The
three Functions built here take the flat scaled controls ``U = [z_0; …; z_{N−1}]`` and ``p``:

``cost``
    ``(objective, penalty)``: the penalty holds what a box search cannot hold by construction
    (terminal equalities with ``terminal_penalty``, rate-bound excess with ``rate_penalty``,
    other hard constraints with ``constraint_penalty``; all exact L1 terms).
``rollout``
    the predicted states ``(nx, N + 1)``.
``score_terms``
    the objective and the raw violations that :func:`uuv_ocp.score` reports.
``decode``
    the search coordinates of the derivative-free solvers ``W ∈ [-1, 1]^{nu N}`` -> ``U``:
    ``z_k = lo_k + (w_k + 1)/2 · (hi_k − lo_k)`` with ``[lo_k, hi_k]`` the control box
    intersected with the rate box ``[z_{k−1} − r, z_{k−1} + r]``, so every candidate holds
    the box **and** the rate bound by construction (the identity without rate bounds).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import casadi as ca
import numpy as np

from uuv_ocp.transcription.multiple_shooting import parameter_blocks, violation

if TYPE_CHECKING:
    from uuv_ocp.build import Transcribed
    from uuv_ocp.ocp import OcpSpec

SCORE_OUTPUTS = ("objective", "terminal_residual", "rate_excess", "bound_excess", "constraint_violation")


def decode(spec: OcpSpec) -> ca.Function:
    """``decode(W, p) -> U``: swarm coordinates to scaled controls holding box and rate bounds."""
    n, nu = spec.horizon, spec.control_size
    coordinates = ca.SX.sym("W", nu * n)
    p = ca.SX.sym("p", spec.layout.size)
    _, u_prev, _, _ = parameter_blocks(spec, p)
    rate_bound = spec.rate_step_bound
    if not (spec.lifted and np.any(np.isfinite(rate_bound))):
        return ca.Function("decode", [coordinates, p], [coordinates], ["W", "p"], ["U"])
    lower, upper = spec.scaled_lower, spec.scaled_upper
    previous = spec.scaled(u_prev)
    scaled = []
    for k in range(n):
        w = coordinates[k * nu : (k + 1) * nu]
        entries = []
        for i in range(nu):
            low, high = lower[i], upper[i]
            if np.isfinite(rate_bound[i]):
                low = ca.fmax(low, previous[i] - rate_bound[i])
                high = ca.fmin(high, previous[i] + rate_bound[i])
            entries.append(low + (w[i] + 1.0) * 0.5 * (high - low))
        previous = ca.vertcat(*entries)
        scaled.append(previous)
    return ca.Function("decode", [coordinates, p], [ca.vertcat(*scaled)], ["W", "p"], ["U"])


def encode(spec: OcpSpec, scaled: np.ndarray, previous: np.ndarray) -> np.ndarray:
    """Inverse of :func:`decode` in numpy: scaled controls (N, nu) -> ``W`` (flat).

    A plan that breaks the rate bound is first projected on it, stage by stage.
    """
    rate_bound = spec.rate_step_bound
    plan = np.asarray(scaled, dtype=float).reshape(spec.horizon, spec.control_size)
    if not (spec.lifted and np.any(np.isfinite(rate_bound))):
        return plan.ravel().copy()
    lower_array, upper_array = spec.scaled_lower, spec.scaled_upper
    prior_rows = np.vstack([np.reshape(previous, (1, -1)), plan[:-1]])
    low_rows = np.maximum(lower_array, prior_rows - rate_bound)
    high_rows = np.minimum(upper_array, prior_rows + rate_bound)
    if np.all((plan >= low_rows) & (plan <= high_rows)):
        # a plan holding both bounds (a shifted plan in a closed loop) projects onto itself,
        # so every stage's window is known at once: the loop's operations, vectorised
        width = high_rows - low_rows
        ratio = np.zeros_like(plan)
        np.divide(2.0 * (plan - low_rows), width, out=ratio, where=width > 0)
        return np.clip(np.where(width > 0, ratio - 1.0, 0.0), -1.0, 1.0).ravel()
    # Python floats: numpy's per-call overhead on vectors of nu entries costs ~10x this loop
    # (the same IEEE operations)
    lower, upper, rate = lower_array.tolist(), upper_array.tolist(), rate_bound.tolist()
    prior = np.asarray(previous, dtype=float).ravel().tolist()
    coordinates = []
    for row in plan.tolist():
        for i, value in enumerate(row):
            low, high = max(lower[i], prior[i] - rate[i]), min(upper[i], prior[i] + rate[i])
            z = min(max(value, low), high) if value == value else value  # NaN stays NaN
            width = high - low
            w = 2.0 * (z - low) / width - 1.0 if width > 0 else 0.0
            coordinates.append(min(max(w, -1.0), 1.0) if w == w else w)
            prior[i] = z
    return np.array(coordinates)


def condense(spec: OcpSpec, step: ca.Function) -> tuple[ca.Function, ca.Function, ca.Function]:
    """``cost``, ``rollout`` and ``score_terms`` Functions (see the module notes)."""
    n, nu = spec.horizon, spec.control_size
    scaled_all = ca.SX.sym("U", nu * n)
    p = ca.SX.sym("p", spec.layout.size)
    x0, u_prev, pg, nodes = parameter_blocks(spec, p)
    scaled = ca.reshape(scaled_all, nu, n)
    rate_bound = spec.rate_step_bound
    rated = np.flatnonzero(np.isfinite(rate_bound))
    no_previous = ca.DM.zeros(nu)
    states = [x0]
    objective = ca.SX(0)
    rate_excess: list[ca.SX] = []
    hard_violation: list[ca.SX] = []
    scaled_prev = spec.scaled(u_prev)

    def constrain(constraint, values: ca.SX) -> None:
        nonlocal objective
        excess = violation(values, constraint.lower, constraint.upper)
        if constraint.soft is None:
            hard_violation.append(excess)
        else:
            objective += constraint.soft * ca.sum1(excess)

    for k in range(n):
        state = states[-1]
        control = spec.physical(scaled[:, k])
        previous = spec.physical(scaled_prev) if spec.lifted else no_previous
        args = (state, control, previous, pg, nodes[k])
        for start, function in spec.stage_residual:
            if k >= start:
                objective += ca.sumsqr(function(*args))
        for start, function in spec.stage_expression:
            if k >= start:
                objective += function(*args)
        for constraint, function in spec.constraints:
            on_node = constraint.place == "node" and k > 0
            if constraint.place == "stage" or on_node or (constraint.place == "initial" and k == 0):
                constrain(constraint, function(*args))
        if spec.lifted and rated.size:
            increment = ca.fabs(scaled[:, k] - scaled_prev)
            rate_excess.append(ca.vertcat(*[ca.fmax(0, increment[int(i)] - rate_bound[i]) for i in rated]))
        states.append(step(state, control, nodes[k], pg))
        scaled_prev = scaled[:, k]
    final = states[-1]
    if spec.terminal_residual is not None:
        objective += ca.sumsqr(spec.terminal_residual(final, pg, nodes[n]))
    if spec.terminal_expression is not None:
        objective += spec.terminal_expression(final, pg, nodes[n])
    terminal_residuals: list[ca.SX] = []
    final_args = (final, no_previous, no_previous, pg, nodes[n])
    for constraint, function in spec.constraints:
        if constraint.place == "node":
            constrain(constraint, function(*final_args))
        elif constraint.place == "terminal":
            values = function(final, pg, nodes[n])
            if constraint.soft is None and np.all(constraint.equality):
                terminal_residuals.append(values - ca.DM(constraint.lower))
            else:
                constrain(constraint, values)

    def stacked(parts: list[ca.SX]) -> ca.SX:
        return ca.vertcat(*parts) if parts else ca.SX.zeros(1)

    terminal_residual = stacked(terminal_residuals)
    rate_vector = stacked(rate_excess)
    constraint_vector = stacked(hard_violation)
    bound_excess = violation(scaled_all, np.tile(spec.scaled_lower, n), np.tile(spec.scaled_upper, n))
    penalty = (
        spec.terminal_penalty * ca.sum1(ca.fabs(terminal_residual))
        + spec.rate_penalty * ca.sum1(rate_vector)
        + spec.constraint_penalty * ca.sum1(constraint_vector)
    )
    cost = ca.Function("cost", [scaled_all, p], [objective, penalty], ["U", "p"], ["objective", "penalty"])
    rollout = ca.Function("rollout", [scaled_all, p], [ca.horzcat(*states)], ["U", "p"], ["X"])
    score_terms = ca.Function(
        "score_terms",
        [scaled_all, p],
        [objective, terminal_residual, rate_vector, bound_excess, constraint_vector],
        ["U", "p"],
        list(SCORE_OUTPUTS),
    )
    return cost, rollout, score_terms


def candidate_fitness(problem: Transcribed) -> ca.Function:
    """``fitness(W[nu N], p) -> objective + penalty`` of one candidate, as an SX Function.

    ``W`` are the search coordinates of :func:`uuv_ocp.transcription.condensed.decode`: every
    ``W`` in ``[-1, 1]^{nu N}`` maps to controls that hold the box and the rate bound.
    """
    built = problem.build()
    coordinates = ca.SX.sym("W", problem.control_dim)
    p = ca.SX.sym("p", problem.parameter_dim)
    objective, penalty = built.cost(built.decode(coordinates, p), p)
    return ca.Function("fitness", [coordinates, p], [objective + penalty], ["W", "p"], ["fitness"])


def batched_fitness(problem: Transcribed, population: int, parallelization: str = "serial") -> ca.Function:
    """``fitness(U[3N × population], p) -> (1 × population)``: objective + penalty, mapped."""
    return candidate_fitness(problem).map("fitness_batch", parallelization, population, [1], [])
