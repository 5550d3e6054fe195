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
from typing import TYPE_CHECKING, Any

import casadi as ca
import numpy as np

from uuv_ocp.transcription.base import Transcription, transcription

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
    interval_index: np.ndarray  # (N, m) positions of the strategy's interval variables (m = 0: none)
    primal_shift: np.ndarray = field(repr=False)
    constraint_shift: np.ndarray = field(repr=False)
    #: multiple shooting: per interval ``(k, x_k, u_k, p_stage, p_global, X_{k+1}, z_k or None)``,
    #: the step's arguments and the gap's other terms (its rows are ``X_{k+1} − [F(x_k, u_k); z_k]``),
    #: and ``(dynamics, dt, substeps)`` of the RK4 step ``F``: the C step's stage data take the
    #: gap's Jacobian from :func:`~uuv_ocp.integrators.rk4_sensitivity` instead of differentiating
    #: the unrolled step (``()`` and ``None``: another transcription)
    shooting: tuple[tuple[Any, ...], ...] = field(default=(), repr=False)
    rk4: tuple[ca.Function, float, int] | None = field(default=None, repr=False)


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


class _Rows:
    """The NLP's variables and constraint rows in the order they are added, and its cost terms."""

    def __init__(self) -> None:
        self.variables: list[tuple[Key, ca.SX, float, float]] = []
        self.constraints: list[tuple[Key, ca.SX, float, float, bool]] = []
        self.residuals: list[ca.SX] = []
        self.linear = ca.SX(0)  # exact-penalty slack terms
        self.other = ca.SX(0)  # expression (non-least-squares) costs
        self.shooting: list[tuple[Any, ...]] = []  # NlpData.shooting

    def variable(self, kind: str, stage: int | None, size: int, lower: object, upper: object) -> ca.SX:
        symbol = ca.SX.sym(f"{kind}_{stage}" if stage is not None else kind, size)
        low = np.broadcast_to(np.asarray(lower, dtype=float), (size,))
        high = np.broadcast_to(np.asarray(upper, dtype=float), (size,))
        for i in range(size):
            self.variables.append(((kind, stage, i), symbol[i], float(low[i]), float(high[i])))
        return symbol

    def rows(self, kind: str, stage: int | None, expression: ca.SX, lower: object, upper: object) -> None:
        size = expression.numel()
        low = np.broadcast_to(np.asarray(lower, dtype=float), (size,))
        high = np.broadcast_to(np.asarray(upper, dtype=float), (size,))
        for i in range(size):
            self.constraints.append(
                ((kind, stage, i), expression[i], float(low[i]), float(high[i]), bool(low[i] == high[i]))
            )

    def relaxed(
        self,
        path: list,
        kind: str,
        stage: int | None,
        values: ca.SX,
        bounds: tuple,
        weight: float,
        slack_kind: str | None = None,
    ) -> None:
        """Queue ``lower <= values <= upper`` relaxed by slacks ``s >= 0`` with the L1 cost ``weight Σ s``.

        A side whose bounds are all infinite gets no rows: ``values + s >= −inf`` holds always,
        and a solver carries such a row anyway (HPIPM: a masked general row in each of its
        iterations; the REMUS 100 survey's path end, 6 -> 5 rows a stage).
        """
        lower, upper = bounds
        slack = self.variable(slack_kind or f"{kind}_slack", stage, values.numel(), 0.0, np.inf)
        if np.any(np.isfinite(upper)):
            path.append((f"{kind}_upper", stage, values - slack, -np.inf, upper))
        if np.any(np.isfinite(lower)):
            path.append((f"{kind}_lower", stage, values + slack, lower, np.inf))
        self.linear += weight * ca.sum1(slack)


@dataclass(frozen=True)
class _Instance:
    """What every stage reads: the problem, the step, the parameter blocks and the variant."""

    spec: OcpSpec
    step: ca.Function
    strategy: Transcription
    x0: ca.SX
    u_prev: ca.SX
    pg: ca.SX
    nodes: list[ca.SX]
    soft_terminal: bool
    terminal_penalty: float


def transcribe(spec: OcpSpec, step: ca.Function, soft_terminal: bool, terminal_penalty: float) -> NlpData:
    """Build the hard NLP (``soft_terminal=False``) or its exact-penalty terminal relaxation."""
    p = ca.SX.sym("p", spec.layout.size)
    x0, u_prev, pg, nodes = parameter_blocks(spec, p)
    instance = _Instance(
        spec=spec,
        step=step,
        strategy=transcription(spec.transcription),
        x0=x0,
        u_prev=u_prev,
        pg=pg,
        nodes=nodes,
        soft_terminal=soft_terminal,
        terminal_penalty=terminal_penalty,
    )
    rows = _Rows()
    lifted_dim = spec.state_dim + spec.control_size if spec.lifted else spec.state_dim
    lifted = rows.variable("X", 0, lifted_dim, -np.inf, np.inf)
    for k in range(spec.horizon):
        lifted = _stage(instance, rows, k, lifted)
    _terminal(instance, rows, lifted[: spec.state_dim])
    return _nlp_data(spec, p, rows)


def _constrain(rows: _Rows, path: list, kind: str, stage: int | None, values: ca.SX, constraint: Any) -> None:
    """Queue a declared constraint's rows: as they are, or relaxed when it is soft."""
    if constraint.soft is None:
        path.append((kind, stage, values, constraint.lower, constraint.upper))
    else:
        rows.relaxed(path, kind, stage, values, (constraint.lower, constraint.upper), constraint.soft)


def _stage(instance: _Instance, rows: _Rows, k: int, lifted: ca.SX) -> ca.SX:
    """Add stage ``k`` (its control, slacks, collocation states, costs and rows); return ``X_{k+1}``.

    Rows come in fatrop's order: the gap ``X_{k+1} − [F(x_k, u_k); z_k]`` first, then the
    stage's path rows.
    """
    spec, pg = instance.spec, instance.pg
    n, nx = spec.horizon, spec.state_dim
    state = lifted[:nx]
    no_previous = ca.DM.zeros(spec.control_size)
    previous = spec.physical(lifted[nx:]) if spec.lifted else no_previous
    scaled = rows.variable("z", k, spec.control_size, spec.scaled_lower, spec.scaled_upper)
    control = spec.physical(scaled)
    stage_p = instance.nodes[k]
    path: list[tuple[str, int | None, ca.SX, object, object]] = []
    if k == 0:
        initial = ca.vertcat(instance.x0, spec.scaled(instance.u_prev)) if spec.lifted else instance.x0
        path.append(("initial", None, lifted - initial, 0.0, 0.0))
    args = (state, control, previous, pg, stage_p)
    rows.residuals += [function(*args) for start, function in spec.stage_residual if k >= start]
    for start, function in spec.stage_expression:
        if k >= start:
            rows.other += function(*args)
    rate_bound = spec.rate_step_bound
    if spec.lifted:
        increment = scaled - lifted[nx:]
        for i in np.flatnonzero(np.isfinite(rate_bound)):
            path.append((f"rate{i}", k, increment[int(i)], -rate_bound[i], rate_bound[i]))
    for j, (constraint, function) in enumerate(spec.constraints):
        on_node = constraint.place == "node" and k > 0
        if constraint.place == "stage" or on_node or (constraint.place == "initial" and k == 0):
            _constrain(rows, path, f"c{j}", k, function(*args), constraint)
    # the strategy's interval: its variables are inputs of stage k (between z_k and X_{k+1},
    # where fatrop and the OCP-QP map take them), its rows this stage's rows
    strategy = instance.strategy
    size = strategy.interval_size(spec)
    variables = rows.variable(strategy.variable_kind, k, size, -np.inf, np.inf) if size else ca.SX(0, 1)
    interval_rows, next_state = strategy.interval(spec, instance.step, variables, state, control, stage_p, pg)
    if interval_rows.numel():
        path.append((strategy.row_kind, k, interval_rows, 0.0, 0.0))
    if k == n - 1:
        _last_stage_rows(instance, rows, path, next_state, control)
    following = rows.variable("X", k + 1, lifted.numel(), -np.inf, np.inf)
    if strategy.name == "multiple_shooting":
        rows.shooting.append((k, state, control, stage_p, pg, following, scaled if spec.lifted else None))
    target = ca.vertcat(next_state, scaled) if spec.lifted else next_state
    rows.rows("dynamics", k, following - target, 0.0, 0.0)
    for kind, stage, values, lower, upper in path:
        rows.rows(kind, stage, values, lower, upper)
    return following


def _last_stage_rows(instance: _Instance, rows: _Rows, path: list, next_state: ca.SX, control: ca.SX) -> None:
    """Node-N rows that need slacks, written on ``F(x_{N−1}, u_{N−1})`` in stage N−1.

    fatrop's last stage has no controls to hold slacks.
    """
    spec, pg, final_p = instance.spec, instance.pg, instance.nodes[instance.spec.horizon]
    no_previous = ca.DM.zeros(spec.control_size)
    for j, (constraint, function) in enumerate(spec.constraints):
        relaxed = instance.soft_terminal and constraint.soft is None and bool(np.all(constraint.equality))
        if constraint.place == "terminal" and relaxed:
            values = function(next_state, pg, final_p)
            # one kind for every terminal slack: NlpData.terminal_slack_index finds them by it
            penalty = instance.terminal_penalty
            rows.relaxed(path, f"terminal{j}", None, values, (0.0, 0.0), penalty, "terminal_slack")
        elif constraint.soft is not None and constraint.place in ("node", "terminal"):
            if constraint.place == "terminal":
                values = function(next_state, pg, final_p)
            else:
                values = function(next_state, control, no_previous, pg, final_p)
            _constrain(rows, path, f"c{j}", spec.horizon, values, constraint)


def _terminal(instance: _Instance, rows: _Rows, final_state: ca.SX) -> None:
    """Terminal costs and the hard node-N and terminal rows (on ``X_N`` itself)."""
    spec, pg, final_p = instance.spec, instance.pg, instance.nodes[instance.spec.horizon]
    if spec.terminal_residual is not None:
        rows.residuals.append(spec.terminal_residual(final_state, pg, final_p))
    if spec.terminal_expression is not None:
        rows.other += spec.terminal_expression(final_state, pg, final_p)
    no_previous = ca.DM.zeros(spec.control_size)
    final_args = (final_state, no_previous, no_previous, pg, final_p)
    for j, (constraint, function) in enumerate(spec.constraints):
        if constraint.soft is not None:
            continue
        if constraint.place == "node":
            rows.rows(f"c{j}", spec.horizon, function(*final_args), constraint.lower, constraint.upper)
        elif constraint.place == "terminal" and not (instance.soft_terminal and np.all(constraint.equality)):
            values = function(final_state, pg, final_p)  # (relaxed in the last stage otherwise)
            rows.rows(f"terminal{j}", None, values, constraint.lower, constraint.upper)


def _nlp_data(spec: OcpSpec, p: ca.SX, rows: _Rows) -> NlpData:
    """Return the NLP of ``rows`` for ``casadi.nlpsol``, with its index maps."""
    strategy = transcription(spec.transcription)
    n, nx = spec.horizon, spec.state_dim
    residual = ca.vertcat(*rows.residuals) if rows.residuals else ca.SX(0, 1)
    objective = ca.sumsqr(residual) + rows.linear + rows.other
    w = ca.vertcat(*[entry[1] for entry in rows.variables])
    g = ca.vertcat(*[entry[1] for entry in rows.constraints]) if rows.constraints else ca.SX(0, 1)
    variable_keys = tuple(entry[0] for entry in rows.variables)
    constraint_keys = tuple(entry[0] for entry in rows.constraints)
    position = {key: i for i, key in enumerate(variable_keys)}

    def positions(kind: str, stages: range, size: int) -> np.ndarray:
        indices = [[position[(kind, k, i)] for i in range(size)] for k in stages]
        return np.array(indices, dtype=int).reshape(len(stages), size)

    lifted_dim = nx + spec.control_size if spec.lifted else nx
    return NlpData(
        nlp={"x": w, "p": p, "f": objective, "g": g},
        residual=residual,
        other_objective=rows.other + rows.linear,
        lbx=np.array([entry[2] for entry in rows.variables], dtype=float),
        ubx=np.array([entry[3] for entry in rows.variables], dtype=float),
        lbg=np.array([entry[2] for entry in rows.constraints], dtype=float),
        ubg=np.array([entry[3] for entry in rows.constraints], dtype=float),
        equality=[bool(entry[4]) for entry in rows.constraints],
        variable_keys=variable_keys,
        constraint_keys=constraint_keys,
        state_index=positions("X", range(n + 1), nx),
        control_index=positions("z", range(n), spec.control_size),
        lifted_index=positions("X", range(n + 1), lifted_dim),
        interval_index=positions(strategy.variable_kind, range(n), strategy.interval_size(spec)),
        terminal_slack_index=np.array(
            [i for i, key in enumerate(variable_keys) if key[0] == "terminal_slack"], dtype=int
        ),
        primal_shift=shift_map(variable_keys),
        constraint_shift=shift_map(constraint_keys),
        shooting=tuple(rows.shooting),
        rk4=(spec.dynamics, spec.dt, spec.substeps) if rows.shooting else None,
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
