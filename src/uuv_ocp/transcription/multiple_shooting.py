"""Multiple-shooting NLP of an :class:`~uuv_ocp.ocp.OcpSpec` for ``casadi.nlpsol``.

Stage ``k`` carries the lifted state ``X_k = [x_k, z_{k−1}]`` (the previous scaled control, so
that rate bounds are stage-local; only ``x_k`` when the problem has no rate bound and no
``previous()`` control) and the scaled control ``z_k``.  Per stage the constraints come in the
order fatrop's structure detection wants: the gap-closing ``X_{k+1} − [F(x_k, u_k); z_k]``
first, then the stage's path constraints.  The objective is ``‖r‖² + ℓ_lin + ℓ_other`` with
``r`` the stacked least-squares residuals (the Gauss–Newton SQP uses ``2 JᵣᵀJᵣ`` plus the exact
Hessian of ``ℓ_other``), ``ℓ_lin`` the slack penalties and ``ℓ_other`` the expression costs.

Every variable and constraint entry has a structured key ``(kind, stage, index)`` (stage
``None`` for entries that do not move with the horizon): warm starts shift stage ``k + 1`` to
``k`` and move iterates between the hard and the soft NLP by these keys.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import casadi as ca
import numpy as np

from uuv_ocp.transcription.collocation import collocation_residual

if TYPE_CHECKING:
    from uuv_ocp.ocp import OcpSpec


Key = tuple[str, "int | None", int]


@dataclass(frozen=True)
class NlpData:
    """A multiple-shooting NLP ready for ``casadi.nlpsol`` and its index maps."""

    nlp: dict[str, ca.SX]
    residual: ca.SX
    other_objective: ca.SX
    lbx: np.ndarray
    ubx: np.ndarray
    lbg: np.ndarray
    ubg: np.ndarray
    equality: list[bool]
    variable_keys: tuple[Key, ...]
    constraint_keys: tuple[Key, ...]
    state_index: np.ndarray
    control_index: np.ndarray
    lifted_index: np.ndarray
    terminal_slack_index: np.ndarray
    collocation_index: np.ndarray  # (N, degree·nx) positions of the collocation states; (N, 0) without
    primal_shift: np.ndarray = field(repr=False)
    constraint_shift: np.ndarray = field(repr=False)


def parameter_blocks(spec: OcpSpec, p: ca.SX) -> tuple[ca.SX, ca.SX, ca.SX, list[ca.SX]]:
    """Symbolic ``p`` -> (x0, u_prev, p_global, [p_stage at node k for k = 0..N])."""
    layout = spec.layout
    globals_: list[tuple[slice, int]] = []
    stagewise: list[tuple[slice, int]] = []
    for part, size, is_stagewise in layout.entries.values():
        (stagewise if is_stagewise else globals_).append((part, size))
    pg = ca.vertcat(*[p[part] for part, _ in globals_]) if globals_ else ca.SX(0, 1)
    nodes = []
    for k in range(spec.horizon + 1):
        blocks = [p[part.start + k * size : part.start + (k + 1) * size] for part, size in stagewise]
        nodes.append(ca.vertcat(*blocks) if blocks else ca.SX(0, 1))
    return p[layout.x0], p[layout.u_prev], pg, nodes


def violation(values: ca.SX, lower: np.ndarray, upper: np.ndarray) -> ca.SX:
    """Elementwise ``max(0, values − upper) + max(0, lower − values)`` (finite sides only)."""
    terms = ca.SX.zeros(values.numel())
    for i in range(values.numel()):
        if np.isfinite(upper[i]):
            terms[i] += ca.fmax(0, values[i] - upper[i])
        if np.isfinite(lower[i]):
            terms[i] += ca.fmax(0, lower[i] - values[i])
    return terms


def transcribe(spec: OcpSpec, step: ca.Function, soft_terminal: bool, terminal_penalty: float) -> NlpData:
    """Build the hard NLP (``soft_terminal=False``) or its exact-penalty terminal relaxation."""
    n, nx, nu = spec.horizon, spec.state_dim, spec.control_size
    p = ca.SX.sym("p", spec.layout.size)
    x0, u_prev, pg, nodes = parameter_blocks(spec, p)
    z_lower, z_upper = spec.scaled_lower, spec.scaled_upper
    rate_bound = spec.rate_step_bound
    rated = np.flatnonzero(np.isfinite(rate_bound))
    lifted_dim = nx + nu if spec.lifted else nx
    no_previous = ca.DM.zeros(nu)
    variables: list[tuple[Key, ca.SX, float, float]] = []
    constraints: list[tuple[Key, ca.SX, float, float, bool]] = []

    def add_variables(kind: str, stage: int | None, size: int, lower: object, upper: object) -> ca.SX:
        symbol = ca.SX.sym(f"{kind}_{stage}" if stage is not None else kind, size)
        low = np.broadcast_to(np.asarray(lower, dtype=float), (size,))
        high = np.broadcast_to(np.asarray(upper, dtype=float), (size,))
        for i in range(size):
            variables.append(((kind, stage, i), symbol[i], float(low[i]), float(high[i])))
        return symbol

    def add_constraints(
        kind: str, stage: int | None, expression: ca.SX, lower: object, upper: object
    ) -> None:
        size = expression.numel()
        low = np.broadcast_to(np.asarray(lower, dtype=float), (size,))
        high = np.broadcast_to(np.asarray(upper, dtype=float), (size,))
        for i in range(size):
            constraints.append(
                ((kind, stage, i), expression[i], float(low[i]), float(high[i]), low[i] == high[i])
            )

    linear = ca.SX(0)
    other = ca.SX(0)
    residuals: list[ca.SX] = []
    path: list[tuple[str, int | None, ca.SX, object, object]] = []

    def constrain(
        kind: str, stage: int | None, values: ca.SX, lower: np.ndarray, upper: np.ndarray, soft
    ) -> None:
        nonlocal linear
        if soft is None:
            path.append((kind, stage, values, lower, upper))
            return
        slack = add_variables(f"{kind}_slack", stage, values.numel(), 0.0, np.inf)
        path.append((f"{kind}_upper", stage, values - slack, -np.inf, upper))
        path.append((f"{kind}_lower", stage, values + slack, lower, np.inf))
        linear += soft * ca.sum1(slack)

    collocated = spec.transcription == "collocation"
    collocation = collocation_residual(spec.dynamics, spec.dt, spec.degree) if collocated else None
    lifted = add_variables("X", 0, lifted_dim, -np.inf, np.inf)
    for k in range(n):
        state = lifted[:nx]
        previous = spec.physical(lifted[nx:]) if spec.lifted else no_previous
        scaled = add_variables("z", k, nu, z_lower, z_upper)
        control = spec.physical(scaled)
        stage_p = nodes[k]
        path = []
        if k == 0:
            initial = ca.vertcat(x0, spec.scaled(u_prev)) if spec.lifted else x0
            path.append(("initial", None, lifted - initial, 0.0, 0.0))
        args = (state, control, previous, pg, stage_p)
        for start, function in spec.stage_residual:
            if k >= start:
                residuals.append(function(*args))
        for start, function in spec.stage_expression:
            if k >= start:
                other += function(*args)
        if spec.lifted and rated.size:
            increment = scaled - lifted[nx:]
            for i in rated:
                path.append((f"rate{i}", k, increment[int(i)], -rate_bound[i], rate_bound[i]))
        for j, (constraint, function) in enumerate(spec.constraints):
            on_node = constraint.place == "node" and k > 0
            if constraint.place == "stage" or on_node or (constraint.place == "initial" and k == 0):
                constrain(f"c{j}", k, function(*args), constraint.lower, constraint.upper, constraint.soft)
        if collocation is not None:
            # direct collocation: the interval's collocation states are variables of stage k
            # (between z_k and X_{k+1}, where fatrop and the OCP-QP map take stage inputs) and
            # their equations rows of this stage; the end state is the last point's
            points = add_variables("K", k, spec.degree * nx, -np.inf, np.inf)
            path.append(("collocation", k, collocation(points, state, control, stage_p, pg), 0.0, 0.0))
            next_state = points[(spec.degree - 1) * nx :]
        else:
            next_state = step(state, control, stage_p, pg)
        if k == n - 1:
            # node-N constraints that need slacks are written on F(x_{N-1}, u_{N-1}) in this
            # stage: fatrop's last stage has no controls to hold them
            final_args = (next_state, control, no_previous, pg, nodes[n])
            for j, (constraint, function) in enumerate(spec.constraints):
                relaxed = soft_terminal and constraint.soft is None and bool(np.all(constraint.equality))
                if constraint.place == "terminal" and relaxed:
                    values = function(next_state, pg, nodes[n])
                    slack = add_variables("terminal_slack", None, values.numel(), 0.0, np.inf)
                    path.append((f"terminal{j}_upper", None, values - slack, -np.inf, 0.0))
                    path.append((f"terminal{j}_lower", None, values + slack, 0.0, np.inf))
                    linear += terminal_penalty * ca.sum1(slack)
                elif constraint.soft is not None and constraint.place in ("node", "terminal"):
                    values = (
                        function(next_state, pg, nodes[n])
                        if constraint.place == "terminal"
                        else function(*final_args)
                    )
                    constrain(f"c{j}", n, values, constraint.lower, constraint.upper, constraint.soft)
        following = add_variables("X", k + 1, lifted_dim, -np.inf, np.inf)
        target = ca.vertcat(next_state, scaled) if spec.lifted else next_state
        add_constraints("dynamics", k, following - target, 0.0, 0.0)
        for kind, stage, values, lower, upper in path:
            add_constraints(kind, stage, values, lower, upper)
        lifted = following
    final_state = lifted[:nx]
    if spec.terminal_residual is not None:
        residuals.append(spec.terminal_residual(final_state, pg, nodes[n]))
    if spec.terminal_expression is not None:
        other += spec.terminal_expression(final_state, pg, nodes[n])
    final_args = (final_state, no_previous, no_previous, pg, nodes[n])
    for j, (constraint, function) in enumerate(spec.constraints):
        if constraint.soft is not None:
            continue
        if constraint.place == "node":
            add_constraints(f"c{j}", n, function(*final_args), constraint.lower, constraint.upper)
        elif constraint.place == "terminal":
            if soft_terminal and np.all(constraint.equality):
                continue  # relaxed above
            add_constraints(
                f"terminal{j}", None, function(final_state, pg, nodes[n]), constraint.lower, constraint.upper
            )
    residual = ca.vertcat(*residuals) if residuals else ca.SX(0, 1)
    objective = ca.sumsqr(residual) + linear + other
    w = ca.vertcat(*[entry[1] for entry in variables])
    g = ca.vertcat(*[entry[1] for entry in constraints]) if constraints else ca.SX(0, 1)
    variable_keys = tuple(entry[0] for entry in variables)
    constraint_keys = tuple(entry[0] for entry in constraints)
    position = {key: i for i, key in enumerate(variable_keys)}

    def positions(kind: str, stages: range, size: int, first: int = 0) -> np.ndarray:
        return np.array([[position[(kind, k, first + i)] for i in range(size)] for k in stages], dtype=int)

    return NlpData(
        nlp={"x": w, "p": p, "f": objective, "g": g},
        residual=residual,
        other_objective=other + linear,
        lbx=np.array([entry[2] for entry in variables], dtype=float),
        ubx=np.array([entry[3] for entry in variables], dtype=float),
        lbg=np.array([entry[2] for entry in constraints], dtype=float),
        ubg=np.array([entry[3] for entry in constraints], dtype=float),
        equality=[bool(entry[4]) for entry in constraints],
        variable_keys=variable_keys,
        constraint_keys=constraint_keys,
        state_index=positions("X", range(n + 1), nx),
        control_index=positions("z", range(n), nu),
        lifted_index=positions("X", range(n + 1), lifted_dim),
        collocation_index=positions("K", range(n), spec.degree * nx).reshape(n, spec.degree * nx),
        terminal_slack_index=np.array(
            [i for i, key in enumerate(variable_keys) if key[0] == "terminal_slack"], dtype=int
        ),
        primal_shift=shift_map(variable_keys),
        constraint_shift=shift_map(constraint_keys),
    )


def shift_map(keys: tuple[Key, ...]) -> np.ndarray:
    """Index array ``source`` with ``shifted = values[source]`` moving every stage k+1 to k."""
    position = {key: i for i, key in enumerate(keys)}
    return np.array(
        [
            position.get((kind, stage + 1, index), i) if stage is not None else i
            for i, (kind, stage, index) in enumerate(keys)
        ],
        dtype=int,
    )


def transfer_map(source: tuple[Key, ...], target: tuple[Key, ...]) -> np.ndarray:
    """For each target key, its index in ``source`` or -1."""
    position = {key: i for i, key in enumerate(source)}
    return np.array([position.get(key, -1) for key in target], dtype=int)
