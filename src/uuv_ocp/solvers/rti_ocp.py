"""The real-time iteration in C on HPIPM's OCP-QP API (``sqp-rti`` with ``qpsol="hpipm-ocp"``).

The multiple-shooting NLP (:mod:`uuv_ocp.transcription.multiple_shooting`) is mapped onto
HPIPM's stage-wise QP in the step ``d``: stage ``k`` has the state ``x_k = ΔX_k`` (the lifted
state) and the input ``u_k`` = every other variable between ``X_k`` and ``X_{k+1}`` (the scaled
control ``z_k`` and the slacks written at that stage, e.g. the soft NLP's terminal slacks at
stage N−1, so the exact-penalty NLP is the same QP, L1 weight included).

* dynamics: the gap ``X_{k+1} − F(X_k, u_k)`` linearised, ``x_{k+1} = A_k x_k + B_k u_k + b_k``
  with ``A, B = −∂g/∂(X_k, u_k)`` and ``b = −g`` (checked: ``∂g/∂X_{k+1} = I``);
* cost: ``Q, S, R`` the stage blocks of the Gauss–Newton Hessian ``2 s JᵣᵀJᵣ`` (+ the exact
  Hessian of the non-least-squares terms), ``q, r`` the gradient (checked block diagonal);
* boxes (``idxbx``/``idxbu``) only on variables with a finite bound, one-sided bounds masked
  (no ±1e8 boxes); the initial-state rows ``X_0 − [x0; z_prev] = 0`` are the stage-0 box
  ``lbx = ubx``, the only place the measured state enters, so feedback moves that box only;
* every other constraint row (rate bounds, path, terminal) is a general constraint ``C, D`` of
  the one stage whose variables it reads.

Equality first (``qpsol_options["equality_first"]``, default ``"auto"``: on where
:func:`equality_first_flops` says it pays, see :data:`EQUALITY_FIRST_MAX_STAGE_FLOPS`): each QP
is first solved with its equalities alone (dynamics, the fixed ``x_0``, the equality rows of one stage such as
the terminal equality) by one Riccati recursion in the hand-written C; the exact-penalty
slacks are held at their bound and each pair of slack rows that fixes a value becomes one
equality.  If that solution satisfies every inequality (boxes, rate and path rows; no
tolerance), its equalities to rounding and, for held slacks, the sign of their bound's
multiplier (the penalty is exact), it is the QP's solution: the KKT conditions hold.
Otherwise, or where the recursion does not apply (a reduced Hessian that is not positive
definite, equality rows at two stages), HPIPM solves the QP.  In a tracking loop no inequality
is active in most steps once the transient is over (s2: about 5 in 6), and the recursion costs
about one of HPIPM's interior-point iterations.

The stage data are one CasADi Function ``data(w, p)`` (each distinct stage generated once and
called through ``map``: :func:`stage_data_function`) generated as C, compiled with the
hand-written step (``native/rti_hpipm.c``) into one library by
:func:`uuv_ocp.native.compile.compile_functions` (content-addressed cache, checksums) and
called through ``ctypes`` on preallocated numpy buffers.  A structure this mapping does not
cover raises :class:`UnsupportedStructure` (the backend then keeps CasADi's ``conic`` path).
"""

from __future__ import annotations

import ctypes
import math
import numbers
import weakref
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import casadi as ca
import numpy as np

from uuv_ocp.integrators import rk4_sensitivity
from uuv_ocp.native.compile import compile_functions, verify_library
from uuv_ocp.native.hpipm import selected as selected_hpipm
from uuv_ocp.native.runtime import hpipm_link_flags
from uuv_ocp.transcription.multiple_shooting import NlpData

_TEMPLATE = Path(__file__).resolve().parents[1] / "native" / "rti_hpipm.c"
#: HPIPM modes, in the order the C code maps them (``hpipm_mode``)
HPIPM_MODES = ("speed_abs", "speed", "balance", "robust")
#: options of the OCP-QP solver (``qpsol_options`` with ``qpsol="hpipm-ocp"``) and defaults;
#: the tolerances are those CasADi's HPIPM interface uses (the ``"hpipm"`` path's)
OCP_QP_DEFAULTS: dict[str, Any] = {
    "mode": "speed",
    "iter_max": 50,
    "tol_stat": 1e-6,
    "tol_eq": 1e-8,
    "tol_ineq": 1e-8,
    "tol_comp": 1e-8,
    "warm_start": False,
    "cond_horizon": "auto",
    "loose_first_qp": True,
    #: try the QP with its equalities alone first (one Riccati recursion; see the module doc);
    #: ``"auto"``: where its estimated cost per stage is below :data:`EQUALITY_FIRST_MAX_STAGE_FLOPS`
    "equality_first": "auto",
    #: take the fixed first state x_0 out of HPIPM's QP (stage 0 without a state: its value
    #: enters b_0, r_0 and the stage-0 rows' bounds, as acados' x0 elimination); ``False``: x_0
    #: a variable with the box lbx = ubx, the former QP (same solution to the QP tolerance)
    "eliminate_x0": True,
}
#: ``equality_first="auto"``: the Riccati solve is tried first where :func:`equality_first_flops`
#: (one factorisation and ne + 2 passes of the hand-written scalar C) per stage stays below
#: this, by the HPIPM linked.  Per stage, because both it and HPIPM's iterations grow linearly
#: with N: a bound on the total (2.5e5 before) turned it off for s2 from N = 63 on, a step in the
#: cost against N (4x from N = 40 to 80).  Measured (docs/benchmarks.md, issue 29): with the
#: native HPIPM, s2 (4.0e3 flops per stage) gains from it and the BlueROV2 survey (3.0e4) lost
#: 1.5x to HPIPM alone (BLASFEO's AVX2 kernels outrun the scalar loops at 18 lifted states);
#: with the wheel's TARGET_GENERIC BLASFEO the Riccati solve won on both.
EQUALITY_FIRST_MAX_STAGE_FLOPS = {"native": 1.25e4, "wheel": math.inf}
#: ``cond_horizon="auto"``: partial condensing to ``horizon // 4`` stages from this horizon on,
#: faster than none at the same settled error on s2 (docs/solvers.md, the condensing table)
AUTO_CONDENSING_FROM = 8
#: converged mode: residuals 1e-10, as ``HPIPM_DEFAULTS`` of the ``"hpipm"`` path (with 1e-6 the
#: converged point moved by ~1e-6 from IPOPT's optimum; see solvers/rti.py), in ``balance`` mode:
#: ``speed`` stopped at its 50 iterations short of 1e-10 on the s2 QP (4e-5 off), balance took 12
OCP_QP_CONVERGED: dict[str, Any] = {
    "mode": "balance",
    "tol_stat": 1e-10,
    "tol_eq": 1e-10,
    "tol_ineq": 1e-10,
    "tol_comp": 1e-10,
}
#: the settings of the first QP of a converged call with ``loose_first_qp``: those the same
#: ``qpsol_options`` give in ``rti`` mode.  The first Gauss–Newton step from a shifted warm
#: start is large (s2: ‖d‖∞ ≈ 0.09 against 3e-6 for the second), so its QP needs no 1e-10
#: solution; the tight QPs after it decide convergence (same iterations, a third less time in
#: C on s2 and the BlueROV2: ``python -m benchmarks.bench_rti --loose-first-qp``)
LOOSE_SETTINGS = ("mode", "tol_stat", "tol_eq", "tol_ineq", "tol_comp")
#: entries of ``uuv_rti_iterate``'s ``info`` (see :meth:`OcpQpStep.iterate`)
INFO_SIZE = 10
#: stop codes of ``uuv_rti_iterate``
STOP_MAX_ITER, STOP_CONVERGED, STOP_INFEASIBLE, STOP_DEADLINE, STOP_EVALUATION = range(5)


class UnsupportedStructure(ValueError):
    """The NLP does not have the stage structure HPIPM's OCP-QP needs (the message says where)."""


def ocp_qp_options(options: dict[str, Any], converged: bool, horizon: int = 0) -> dict[str, Any]:
    """Check the HPIPM options: the defaults, the converged mode's tolerances, then ``options``.

    ``cond_horizon="auto"`` becomes ``horizon // 4`` stages when ``horizon`` ≥
    :data:`AUTO_CONDENSING_FROM`, else 0 (no partial condensing).  ``loose_first_qp`` stays on
    only in converged mode; ``"loose_settings"`` (added) are the mode and tolerances the same
    ``options`` give in ``rti`` mode, for that first QP.

    Raises
    ------
    ValueError
        An unknown key or a bad value; the message names ``options['qpsol_options'][key]``.
    """
    merged = {**OCP_QP_DEFAULTS, **(OCP_QP_CONVERGED if converged else {})}
    for key, value in options.items():
        name = f"options['qpsol_options'][{key!r}]"
        if key not in OCP_QP_DEFAULTS:
            raise ValueError(
                f"{name} is not an option of qpsol='hpipm-ocp'; valid: {sorted(OCP_QP_DEFAULTS)}"
            )
        if key == "mode" and value not in HPIPM_MODES:
            raise ValueError(f"{name} must be one of {HPIPM_MODES}, got {value!r}")
        integral = isinstance(value, numbers.Integral) and not isinstance(value, bool)
        if key == "iter_max" and not (integral and int(value) >= 1):
            raise ValueError(f"{name} must be an int >= 1, got {value!r}")
        if key == "cond_horizon" and value != "auto" and not (integral and int(value) >= 0):
            raise ValueError(
                f"{name} must be 'auto' or an int >= 0 (0: no partial condensing), got {value!r}"
            )
        if key in ("warm_start", "loose_first_qp", "eliminate_x0") and not isinstance(value, bool):
            raise ValueError(f"{name} must be True or False, got {value!r}")
        if key == "equality_first" and not (isinstance(value, bool) or value == "auto"):
            raise ValueError(f"{name} must be True, False or 'auto', got {value!r}")
        real = isinstance(value, numbers.Real) and not isinstance(value, bool)
        if key.startswith("tol_") and not (real and 0.0 < float(value) < math.inf):
            raise ValueError(f"{name} must be a finite float > 0, got {value!r}")
        count = key == "iter_max" or (key == "cond_horizon" and value != "auto")
        merged[key] = int(value) if count else value
    if merged["cond_horizon"] == "auto":
        merged["cond_horizon"] = horizon // 4 if horizon >= AUTO_CONDENSING_FROM else 0
    merged["loose_first_qp"] = converged and merged["loose_first_qp"]  # rti: one kind of QP
    rti_settings = {**OCP_QP_DEFAULTS, **options}
    merged["loose_settings"] = {key: rti_settings[key] for key in LOOSE_SETTINGS}
    return merged


def equality_first_flops(layout: OcpQpLayout, data: NlpData) -> float:
    """Estimated flops of one equality-first solve (``rti_eq_solve``) of ``layout``'s QP.

    The Riccati factorisation (``P A``, ``P B``, ``R + B'P B``, ``S + B'P A``, ``A'P A``, the
    Cholesky factor and ``Y``) plus ``ne + 2`` solve passes, ``ne`` the most equality rows of
    one stage (each slack pair of the exact-penalty NLP counts as one equality).
    """
    n = layout.horizon
    factor = passes = 0.0
    for k in range(n):
        nx, nu, nx1 = len(layout.xvar[k]), len(layout.uvar[k]), len(layout.xvar[k + 1])
        factor += nx1 * nx1 * (nx + nu) + nu * nx * nx1 + (nu * nu * nx1 + nx * nx * nx1) / 2
        factor += nu**3 / 6 + (nu * nu * nx + nx * nx * nu) / 2
        passes += 2 * (nx1 * nu + nx * nx1 + nx * nu) + nu * nu
    slack = np.array([key[0].endswith("slack") for key in data.variable_keys])
    enforced = [
        int(np.sum(data.lbg[rows] == data.ubg[rows])) + int(np.sum(slack[layout.uvar[k]]))
        for k, rows in enumerate(layout.genrow)
    ]
    return factor + (max(enforced, default=0) + 2) * passes


def resolve_equality_first(options: dict[str, Any], layout: OcpQpLayout, data: NlpData) -> dict[str, Any]:
    """``options`` with ``equality_first="auto"`` decided for this QP and the HPIPM linked.

    The decision compares the estimated flops per stage, so it does not change with the horizon.
    """
    if options.get("equality_first") != "auto":
        return options
    linked = "native" if selected_hpipm() is not None else "wheel"
    per_stage = equality_first_flops(layout, data) / max(layout.horizon, 1)
    pays = per_stage <= EQUALITY_FIRST_MAX_STAGE_FLOPS[linked]
    return {**options, "equality_first": bool(pays)}


@dataclass(frozen=True)
class OcpQpLayout:
    """Where each NLP variable and constraint row sits in HPIPM's stage-wise QP.

    Attributes hold per stage ``k = 0..N`` (dynamics: ``k < N``) the NLP indices in HPIPM's
    order: ``xvar[k]`` (the lifted state), ``uvar[k]`` (control and slacks), ``dynrow[k]``,
    ``genrow[k]``; the box positions within the stage (``idxbx``, ``idxbu``) with their NLP
    variable (``bx_var``/``bu_var``; ``-1 − row`` for a stage-0 initial-state row) and which
    sides are finite (masks); ``x0_box`` the box position of each measured-state entry.
    """

    xvar: tuple[np.ndarray, ...]
    uvar: tuple[np.ndarray, ...]
    dynrow: tuple[np.ndarray, ...]
    genrow: tuple[np.ndarray, ...]
    idxbx: tuple[np.ndarray, ...]
    idxbu: tuple[np.ndarray, ...]
    bx_target: tuple[np.ndarray, ...]
    bu_target: tuple[np.ndarray, ...]
    lbx_mask: tuple[np.ndarray, ...]
    ubx_mask: tuple[np.ndarray, ...]
    lbu_mask: tuple[np.ndarray, ...]
    ubu_mask: tuple[np.ndarray, ...]
    lg_mask: tuple[np.ndarray, ...]
    ug_mask: tuple[np.ndarray, ...]
    x0_box: np.ndarray

    @property
    def horizon(self) -> int:
        """Number of stages N (HPIPM's stages are 0..N)."""
        return len(self.xvar) - 1


def ocp_qp_layout(data: NlpData, state_dim: int) -> OcpQpLayout:
    """Map ``data`` onto HPIPM's OCP-QP (see the module doc) and check that it fits.

    Raises
    ------
    UnsupportedStructure
        Variables before ``X_0``, a dynamics row that is not ``X_{k+1} − F(X_k, u_k)``, a row
        or a Hessian entry coupling two stages, or bounds on ``X_0`` besides the initial rows.
    """
    stage_of, xvar, uvar = _stage_variables(data.variable_keys)
    n = len(xvar) - 1
    jacobian = ca.jacobian(data.nlp["g"], data.nlp["x"])
    columns_of_row = _columns_of_rows(jacobian.sparsity())
    _check_cost_is_stagewise(data, stage_of)
    dynrow, genrow, initial, initial_key = _classify_rows(
        data, jacobian, columns_of_row, stage_of, xvar, uvar
    )
    for k in range(n):
        if len(dynrow[k]) != len(xvar[k + 1]):
            raise UnsupportedStructure(
                f"stage {k}: {len(dynrow[k])} dynamics rows for {len(xvar[k + 1])} states"
            )
        block = jacobian[dynrow[k], xvar[k + 1]]
        if not block.is_constant() or not np.array_equal(np.array(ca.DM(block)), np.eye(len(dynrow[k]))):
            raise UnsupportedStructure(f"stage {k}: the gap is not X_(k+1) − F(X_k, u_k)")
    if any(i not in initial_key for i in range(state_dim)):
        raise UnsupportedStructure("the initial-state rows do not fix the measured state")
    boxes = _boxes(data, xvar, uvar, genrow, initial)
    positions = sorted(initial)
    x0_box = np.array(
        [positions.index(xvar[0].index(columns_of_row[initial_key[i]][0])) for i in range(state_dim)]
    )

    def as_int(group: list[list[int]]) -> tuple[np.ndarray, ...]:
        return tuple(np.array(v, dtype=np.int32) for v in group)

    return OcpQpLayout(
        xvar=as_int(xvar),
        uvar=as_int(uvar),
        dynrow=as_int(dynrow),
        genrow=as_int(genrow),
        **{name: tuple(values) for name, values in boxes.items()},
        x0_box=x0_box.astype(np.int32),
    )


def _stage_variables(keys: tuple) -> tuple[np.ndarray, list[list[int]], list[list[int]]]:
    """Each variable's stage, and per stage the lifted state's and the inputs' NLP indices."""
    if not keys or keys[0][0] != "X":
        raise UnsupportedStructure("the NLP does not start with the lifted state X_0")
    stage_of = np.empty(len(keys), dtype=int)
    xvar: list[list[int]] = []
    uvar: list[list[int]] = []
    for i, (kind, stage, _) in enumerate(keys):
        if kind == "X":
            if stage == len(xvar):
                xvar.append([])
                uvar.append([])
            elif stage != len(xvar) - 1:
                raise UnsupportedStructure(f"lifted states out of order at variable {i}")
            xvar[-1].append(i)
        else:
            uvar[-1].append(i)
        stage_of[i] = len(xvar) - 1
    return stage_of, xvar, uvar


def _columns_of_rows(sparsity: ca.Sparsity) -> list[list[int]]:
    """Return the variables each constraint row reads (the nonzero columns of its Jacobian row)."""
    rows_of_column, colind = sparsity.row(), sparsity.colind()
    columns_of_row: list[list[int]] = [[] for _ in range(sparsity.size1())]
    for column in range(sparsity.size2()):
        for entry in range(colind[column], colind[column + 1]):
            columns_of_row[rows_of_column[entry]].append(column)
    return columns_of_row


def _check_cost_is_stagewise(data: NlpData, stage_of: np.ndarray) -> None:
    """Refuse a Gauss–Newton or exact cost Hessian entry that couples two stages."""
    w = data.nlp["x"]
    residual_jacobian = ca.jacobian(data.residual, w)
    product = ca.mtimes(residual_jacobian.T, residual_jacobian).sparsity()
    other_hessian, _ = ca.hessian(data.other_objective, w)
    for structure in (product, other_hessian.sparsity()):
        rows, columns = structure.get_triplet()
        if np.any(stage_of[np.asarray(rows, dtype=int)] != stage_of[np.asarray(columns, dtype=int)]):
            raise UnsupportedStructure("the cost Hessian couples two stages")


def _classify_rows(
    data: NlpData,
    jacobian: ca.SX,
    columns_of_row: list[list[int]],
    stage_of: np.ndarray,
    xvar: list[list[int]],
    uvar: list[list[int]],
) -> tuple[list[list[int]], list[list[int]], dict[int, int], dict[int, int]]:
    """Sort the rows: dynamics per stage, general rows per stage, initial-state rows.

    Returns the dynamics rows and the general rows per stage, the initial rows by position in
    ``X_0`` and by key index.
    """
    n = len(xvar) - 1
    dynrow: list[list[int]] = [[] for _ in range(n)]
    genrow: list[list[int]] = [[] for _ in range(n + 1)]
    initial: dict[int, int] = {}  # position in X_0 -> row
    initial_key: dict[int, int] = {}  # key index -> row
    for row, (kind, stage, index) in enumerate(data.constraint_keys):
        columns = columns_of_row[row]
        if kind == "dynamics":
            assert stage is not None
            dynrow[stage].append(row)
            allowed = set(xvar[stage]) | set(uvar[stage]) | set(xvar[stage + 1])
            if not set(columns) <= allowed:
                raise UnsupportedStructure(f"dynamics row {row} reads variables of other stages")
            continue
        if kind == "initial":
            single = len(columns) == 1 and stage_of[columns[0]] == 0
            fixed = single and _constant(jacobian[row, columns[0]]) == 1.0
            if not (fixed and data.lbg[row] == data.ubg[row] == 0.0):
                raise UnsupportedStructure(f"initial-state row {row} is not X_0[i] − x0_i = 0")
            initial[xvar[0].index(columns[0])] = row
            initial_key[index] = row
            continue
        stages = {int(stage_of[c]) for c in columns}
        if len(stages) > 1:
            raise UnsupportedStructure(f"constraint row {row} ({kind}) couples stages {sorted(stages)}")
        genrow[stages.pop() if stages else 0].append(row)
    return dynrow, genrow, initial, initial_key


def _boxes(
    data: NlpData,
    xvar: list[list[int]],
    uvar: list[list[int]],
    genrow: list[list[int]],
    initial: dict[int, int],
) -> dict[str, list[np.ndarray]]:
    """Per stage: the box positions, their NLP variables (or initial rows) and finite-side masks."""

    def finite(values: np.ndarray) -> np.ndarray:
        return np.isfinite(values).astype(float)

    def bounded(variables: list[int]) -> list[int]:
        return [j for j, v in enumerate(variables) if np.isfinite(data.lbx[v]) or np.isfinite(data.ubx[v])]

    names = ("idxbx", "idxbu", "bx_target", "bu_target", "lbx_mask", "ubx_mask")
    boxes: dict[str, list[np.ndarray]] = {
        name: [] for name in (*names, "lbu_mask", "ubu_mask", "lg_mask", "ug_mask")
    }
    for k in range(len(xvar)):
        x_bounded = bounded(xvar[k])
        if k == 0:
            if x_bounded:
                raise UnsupportedStructure("X_0 has bounds besides the initial-state rows")
            positions = sorted(initial)
            boxes["idxbx"].append(np.array(positions, dtype=np.int32))
            boxes["bx_target"].append(np.array([-1 - initial[j] for j in positions], dtype=np.int32))
            boxes["lbx_mask"].append(np.ones(len(positions)))
            boxes["ubx_mask"].append(np.ones(len(positions)))
        else:
            boxes["idxbx"].append(np.array(x_bounded, dtype=np.int32))
            variables = np.array([xvar[k][j] for j in x_bounded], dtype=int)
            boxes["bx_target"].append(variables.astype(np.int32))
            boxes["lbx_mask"].append(finite(data.lbx[variables]))
            boxes["ubx_mask"].append(finite(data.ubx[variables]))
        u_bounded = bounded(uvar[k])
        variables = np.array([uvar[k][j] for j in u_bounded], dtype=int)
        boxes["idxbu"].append(np.array(u_bounded, dtype=np.int32))
        boxes["bu_target"].append(variables.astype(np.int32))
        boxes["lbu_mask"].append(finite(data.lbx[variables]))
        boxes["ubu_mask"].append(finite(data.ubx[variables]))
        general = np.array(genrow[k], dtype=int)
        boxes["lg_mask"].append(finite(data.lbg[general]))
        boxes["ug_mask"].append(finite(data.ubg[general]))
    return boxes


def _constant(value: ca.SX) -> float:
    return float(ca.DM(value)) if value.is_constant() else math.nan


#: options of each distinct stage Function: common subexpressions merged, among them the
#: nominal RK4 step of the gap ``b`` and the same step inside its sensitivity (REMUS 100 survey:
#: 35.9k -> 29.8k operations a stage, 0.28 -> 0.22 ms CPU for the stage data of N = 20)
STAGE_FUNCTION_OPTIONS: dict[str, Any] = {"cse": True}


def constraint_jacobian(data: NlpData, sensitivity: bool = True) -> ca.SX:
    """``∂g/∂w`` of the NLP; the multiple-shooting gaps' rows from the RK4 step's sensitivity.

    With ``sensitivity`` (and a multiple-shooting NLP: ``data.shooting``), the rows of each gap
    ``X_{k+1} − [F(x_k, u_k); z_k]`` are ``∂X_{k+1}/∂w − [F_x ∂x_k/∂w + F_u ∂u_k/∂w; ∂z_k/∂w]``
    with ``F_x, F_u`` from :func:`~uuv_ocp.integrators.rk4_sensitivity` (the model's Jacobian
    propagated through the RK4 stages: half the operations of differentiating the unrolled
    step on the REMUS 100); every other row, and every row without it, by ``casadi.jacobian``.
    The two agree to rounding (tests/solvers/test_rti.py).
    """
    w, g = data.nlp["x"], data.nlp["g"]
    if not (sensitivity and data.shooting and data.rk4 is not None):
        return ca.jacobian(g, w)
    step = rk4_sensitivity(*data.rk4)
    where = {key: i for i, key in enumerate(data.constraint_keys)}
    blocks: list[ca.SX] = []
    rows: list[int] = []
    for k, state, control, stage_p, pg, following, scaled in data.shooting:
        _, d_state, d_control = step(state, control, stage_p, pg)
        d_next = ca.mtimes(d_state, ca.jacobian(state, w)) + ca.mtimes(d_control, ca.jacobian(control, w))
        target = d_next if scaled is None else ca.vertcat(d_next, ca.jacobian(scaled, w))
        blocks.append(ca.jacobian(following, w) - target)
        rows += [where[("dynamics", k, i)] for i in range(following.numel())]
    gaps = set(rows)
    others = [i for i in range(g.numel()) if i not in gaps]
    if others:
        blocks.append(ca.jacobian(g[others], w))
    order = np.argsort(np.array(rows + others, dtype=int), kind="stable")
    return ca.vertcat(*blocks)[order.tolist(), :]


BLOCKS = ("A", "B", "b", "Q", "S", "R", "q", "r", "C", "D", "lg", "ug", "lbx", "ubx", "lbu", "ubu")


def stage_data_function(
    data: NlpData,
    layout: OcpQpLayout,
    objective_scale: float,
    still_water_slice: slice | None,
    name: str,
    per_stage: bool = True,
    sensitivity: bool = True,
) -> tuple[ca.Function, np.ndarray]:
    """``name(w, p) -> data``: HPIPM's stage data at ``w`` stacked, and their offsets.

    The offsets array has one row per stage and one column per entry of :data:`BLOCKS`
    (column-major matrices, as HPIPM's setters read them).  Infinite bound sides are written
    as 0 (masked in HPIPM).  With ``still_water_slice`` the current parameters are zero *after*
    differentiation (the same layout, CasADi simplifies the vanished terms).  ``sensitivity``:
    the gaps' Jacobian from the RK4 step's sensitivity (:func:`constraint_jacobian`; ``False``:
    ``casadi.jacobian`` of the unrolled step, the former path, kept as the tests' reference).
    """
    w, p = data.nlp["x"], data.nlp["p"]
    g = data.nlp["g"]
    jacobian = constraint_jacobian(data, sensitivity)
    residual_jacobian = ca.jacobian(data.residual, w)
    hessian = (2.0 * objective_scale) * ca.mtimes(residual_jacobian.T, residual_jacobian)
    other_hessian, _ = ca.hessian(data.other_objective, w)
    if other_hessian.nnz():  # expression costs keep their exact curvature (as NlpSolver)
        hessian += objective_scale * other_hessian
    gradient = objective_scale * ca.gradient(data.nlp["f"], w)
    n = layout.horizon
    pieces: list[ca.SX] = []
    piece_stage: list[int] = []
    offsets = np.zeros((n + 1, len(BLOCKS)), dtype=np.int64)
    position = 0

    def add(block: str, k: int, value: ca.SX) -> None:
        nonlocal position
        offsets[k, BLOCKS.index(block)] = position
        flat = ca.vec(ca.densify(value))
        pieces.append(flat)
        piece_stage.append(k)
        position += flat.numel()

    def bounds(values: np.ndarray, shift: ca.SX) -> ca.SX:
        finite = np.isfinite(values)
        return (
            ca.vertcat(*[(float(v) - shift[i]) if finite[i] else ca.SX(0.0) for i, v in enumerate(values)])
            if values.size
            else ca.SX(0, 1)
        )

    for k in range(n + 1):
        x, u = [int(i) for i in layout.xvar[k]], [int(i) for i in layout.uvar[k]]
        if k < n:
            rows = [int(i) for i in layout.dynrow[k]]
            add("A", k, -jacobian[rows, x])
            add("B", k, -jacobian[rows, u] if u else ca.SX(len(rows), 0))
            add("b", k, -g[rows])
        add("Q", k, hessian[x, x])
        add("S", k, hessian[u, x] if u else ca.SX(0, len(x)))
        add("R", k, hessian[u, u] if u else ca.SX(0, 0))
        add("q", k, gradient[x])
        add("r", k, gradient[u] if u else ca.SX(0, 1))
        rows = [int(i) for i in layout.genrow[k]]
        if rows:
            add("C", k, jacobian[rows, x])
            add("D", k, jacobian[rows, u] if u else ca.SX(len(rows), 0))
            add("lg", k, bounds(data.lbg[rows], g[rows]))
            add("ug", k, bounds(data.ubg[rows], g[rows]))
        bx = [int(i) for i in layout.bx_target[k]]
        if k == 0 and bx:
            # the initial-state rows X_0 − x0 = 0: the box lbx = ubx = −g (feedback moves it)
            add("lbx", k, -g[[-1 - i for i in bx]])
            add("ubx", k, -g[[-1 - i for i in bx]])
        elif bx:
            add("lbx", k, bounds(data.lbx[bx], w[bx]))
            add("ubx", k, bounds(data.ubx[bx], w[bx]))
        bu = [int(i) for i in layout.bu_target[k]]
        if bu:
            add("lbu", k, bounds(data.lbx[bu], w[bu]))
            add("ubu", k, bounds(data.ubx[bu], w[bu]))
    if still_water_slice is not None:
        current = p[still_water_slice]
        pieces = ca.vertsplit(
            ca.substitute(ca.vertcat(*pieces), current, ca.DM.zeros(current.numel())),
            [0, *np.cumsum([piece.numel() for piece in pieces]).tolist()],
        )
    if not per_stage:
        return ca.Function(name, [w, p], [ca.vertcat(*pieces)], ["w", "p"], ["data"]), offsets
    stage_pieces = [
        ca.vertcat(*[piece for piece, stage in zip(pieces, piece_stage, strict=True) if stage == k])
        for k in range(n + 1)
    ]
    return _mapped_stages(name, w, p, stage_pieces, layout), offsets


def _mapped_stages(
    name: str, w: ca.SX, p: ca.SX, stage_pieces: list[ca.SX], layout: OcpQpLayout
) -> ca.Function:
    """Return ``name(w, p)``: the stacked stage data, each distinct stage function generated once.

    Stage ``k``'s data read only ``X_k``, ``u_k``, ``X_{k+1}`` and some parameters.  Written
    over canonical symbols, the stages that are the same expression (serialised the same: the
    middle stages of a tracking problem) become one CasADi Function called through ``map``:
    the generated C holds each distinct stage once instead of the horizon unrolled (a 12-state
    vehicle at N = 20: 5.8 MB of C, minutes to compile, an instruction stream larger than the
    caches), and the outputs are the horizon function's, operation for operation.
    """
    n = layout.horizon
    stages = []
    for k in range(n + 1):
        local = [int(i) for i in layout.xvar[k]] + [int(i) for i in layout.uvar[k]]
        if k < n:
            local += [int(i) for i in layout.xvar[k + 1]]
        expression = stage_pieces[k]
        read = [i for i, used in enumerate(ca.which_depends(expression, p, 1, False)) if used]
        v, q = ca.SX.sym("v", len(local)), ca.SX.sym("q", len(read))
        stage = ca.Function("stage", [w[local], p[read] if read else ca.SX(0, 1)], [expression])
        canonical = (v, q, ca.densify(stage(v, q)))  # dense: the C reads the data by offset
        stages.append((canonical, ca.Function("stage", [v, q], [canonical[2]]).serialize(), local, read))
    distinct: dict[str, list[int]] = {}
    for k, (_, key, _, _) in enumerate(stages):
        distinct.setdefault(key, []).append(k)
    wm, pm = ca.MX.sym("w", w.numel()), ca.MX.sym("p", p.numel())
    outputs: list[ca.MX] = [ca.MX(0, 1)] * (n + 1)
    for number, members in enumerate(distinct.values()):
        v, q, expression = stages[members[0]][0]
        function = ca.Function(f"{name}_s{number}", [v, q], [expression], STAGE_FUNCTION_OPTIONS)
        local_in = ca.horzcat(*[wm[stages[k][2]] for k in members])
        read_in = ca.horzcat(*[pm[stages[k][3]] if stages[k][3] else ca.MX(0, 1) for k in members])
        mapped = function.map(len(members)) if len(members) > 1 else function
        result = mapped(local_in, read_in)
        for column, k in enumerate(members):
            outputs[k] = result[:, column]
    stacked: ca.MX = ca.densify(ca.vertcat(*outputs))
    return ca.Function(name, [wm, pm], [stacked], ["w", "p"], ["data"])


def _c_array(ctype: str, name: str, values: Any) -> str:
    values = list(values)
    body = ", ".join(repr(float(v)) if ctype == "double" else str(int(v)) for v in values) or "0"
    return f"static const {ctype} {name}[{max(len(values), 1)}] = {{{body}}};\n"


def c_source(
    layout: OcpQpLayout,
    function: ca.Function,
    offsets: np.ndarray,
    x0_param: np.ndarray,
    data: NlpData,
    pi_sign: float = -1.0,
    prefix: str = "",
) -> str:
    """Return the hand-written step with this NLP's sizes and index maps (appended to generated C).

    ``data`` gives the sizes and the shift maps of the resident warm start
    (``uuv_rti_resident_step``).

    ``pi_sign``: HPIPM's dynamics multiplier ``π_k`` is minus CasADi's ``λ`` of the gap row
    ``X_{k+1} − F`` (checked by stationarity of the QP's Lagrangian in tests/solvers/test_rti.py).
    """
    n = layout.horizon
    nx = [len(v) for v in layout.xvar]
    nu = [len(v) for v in layout.uvar]
    nbx = [len(v) for v in layout.idxbx]
    nbu = [len(v) for v in layout.idxbu]
    ngs = [len(v) for v in layout.genrow]
    nw, ng = data.lbx.size, data.lbg.size

    def starts(sizes: list[int]) -> list[int]:
        return list(np.concatenate([[0], np.cumsum(sizes)])[:-1]) if sizes else [0]

    lines = [
        f"#define RTI_N {n}\n",
        f"#define RTI_NW {nw}\n",
        f"#define RTI_NG {ng}\n",
        f"#define RTI_NDATA {max(int(function.nnz_out(0)), 1)}\n",
        f"#define RTI_NX0 {len(x0_param)}\n",
        f"#define RTI_NBX0 {max(nbx[0], 1)}\n",
        f"#define RTI_NUX {sum(nx) + sum(nu)}\n",
        f"#define RTI_NLAM {max(2 * (sum(nbx) + sum(nbu) + sum(ngs)), 1)}\n",
        f"#define RTI_NPI {sum(nx[1:])}\n",
        f"#define RTI_MAX_NX {max(max(nx), 1)}\n",
        f"#define RTI_MAX_NU {max(max(nu), 1)}\n",
        f"#define RTI_MAX_NG {max(max(ngs), 1)}\n",
        f"#define RTI_PI_SIGN ({pi_sign!r})\n",
        f"#define RTI_DATA {prefix}{function.name()}\n",
        f"#define RTI_SZ_ARG {max(int(function.sz_arg()), 2)}\n",
        f"#define RTI_SZ_RES {max(int(function.sz_res()), 1)}\n",
        f"#define RTI_SZ_IW {max(int(function.sz_iw()), 1)}\n",
        f"#define RTI_SZ_W {max(int(function.sz_w()), 1)}\n",
        _c_array("int", "rti_nx", nx),
        _c_array("int", "rti_nu", nu),
        _c_array("int", "rti_nbx", nbx),
        _c_array("int", "rti_nbu", nbu),
        _c_array("int", "rti_ng", ngs),
        _c_array("int", "rti_ox", starts(nx)),
        _c_array("int", "rti_ou", starts(nu)),
        _c_array("int", "rti_oux", starts([a + b for a, b in zip(nx, nu, strict=True)])),
        _c_array("int", "rti_obx", starts(nbx)),
        _c_array("int", "rti_obu", starts(nbu)),
        _c_array("int", "rti_ob", starts([a + b for a, b in zip(nbx, nbu, strict=True)])),
        _c_array("int", "rti_og", starts(ngs)),
        _c_array("int", "rti_olam", starts([2 * (a + b + c) for a, b, c in zip(nbx, nbu, ngs, strict=True)])),
        _c_array("int", "rti_xvar", np.concatenate(layout.xvar)),
        _c_array("int", "rti_uvar", np.concatenate(layout.uvar)),
        # inputs that are penalty slacks (the equality-first solve may hold only these at a bound)
        _c_array(
            "int",
            "rti_slack",
            [data.variable_keys[int(v)][0].endswith("slack") for v in np.concatenate(layout.uvar)],
        ),
        _c_array("int", "rti_dynrow", np.concatenate(layout.dynrow) if n else []),
        _c_array("int", "rti_genrow", np.concatenate(layout.genrow)),
        _c_array("int", "rti_idxbx", np.concatenate(layout.idxbx)),
        _c_array("int", "rti_idxbu", np.concatenate(layout.idxbu)),
        # HPIPM's box order: the nbu input boxes, then the nbx state boxes
        _c_array(
            "int",
            "rti_blam",
            np.concatenate(
                [np.concatenate([u, x]) for u, x in zip(layout.bu_target, layout.bx_target, strict=True)]
            ),
        ),
        _c_array("double", "rti_lbx_mask", np.concatenate(layout.lbx_mask)),
        _c_array("double", "rti_ubx_mask", np.concatenate(layout.ubx_mask)),
        _c_array("double", "rti_lbu_mask", np.concatenate(layout.lbu_mask)),
        _c_array("double", "rti_ubu_mask", np.concatenate(layout.ubu_mask)),
        _c_array("double", "rti_lg_mask", np.concatenate(layout.lg_mask)),
        _c_array("double", "rti_ug_mask", np.concatenate(layout.ug_mask)),
        _c_array("int", "rti_x0_param", x0_param),
        _c_array("int", "rti_x0_box", layout.x0_box),
        _c_array("int", "rti_primal_shift", data.primal_shift),
        _c_array("int", "rti_constraint_shift", data.constraint_shift),
        f"static const int rti_off[{n + 1}][{len(BLOCKS)}] = {{"
        + ", ".join("{" + ", ".join(str(int(v)) for v in row) + "}" for row in offsets)
        + "};\n",
    ]
    source = _TEMPLATE.read_text()
    if prefix:
        source = source.replace("uuv_rti_", f"{prefix}uuv_rti_")
    return (
        "/* ---- real-time iteration on HPIPM's OCP-QP (uuv_ocp.solvers.rti_ocp) ---- */\n"
        + "".join(lines)
        + source
    )


#: declarations of the exported C entry points (``{prefix}`` substituted), for the header
C_HEADER = """
void* uuv_rti_create(const double* options);
void uuv_rti_free(void* memory);
int uuv_rti_prepare(void* memory, const double* w, const double* p);
int uuv_rti_iterate(void* memory, double* w, const double* p, int prepared, int max_iter, double tol,
                    double qp_tol, double budget, double* lam_x, double* lam_g, double* info);
void uuv_rti_seed(void* memory, const double* w, const double* lam_x, const double* lam_g);
int uuv_rti_resident_step(void* memory, const double* p, int max_iter, double tol, double qp_tol,
                          int converged_only, double* w, double* lam_x, double* lam_g, double* info);
int uuv_rti_closed_loop_step(void* memory, const void* settings, const double* window);
"""


class ClosedLoopSettings(ctypes.Structure):
    """``rti_closed_loop`` of ``native/rti_hpipm.c``: what ``uuv_rti_closed_loop_step`` reads.

    Pointers to arrays the owner (:class:`~uuv_ocp.solvers.rti.ClosedLoopEntry`) keeps alive;
    the order and types of the C struct (ctypes lays it out as the compiler does).
    """

    _fields_ = [
        *((name, ctypes.c_void_p) for name in ("p", "low", "high", "out", "index", "lower", "upper")),
        *((name, ctypes.c_void_p) for name in ("scale", "centre", "box_lower", "box_upper", "rate", "slack")),
        *((name, ctypes.c_double) for name in ("slack_tol", "tol", "qp_tol")),
        *((name, ctypes.c_int) for name in ("nx", "nu", "heading", "window", "rows", "nslack", "max_iter")),
    ]


class OcpQpStep:
    """One compiled RTI step of one NLP variant, with its HPIPM memory (allocated once).

    Not thread-safe: the HPIPM memory and the call buffers serve one call at a time (a copy or
    an unpickled step gets memory of its own).

    Parameters
    ----------
    library : pathlib.Path
        The checked library holding ``uuv_rti_*`` (see :func:`build_step`).
    sizes : tuple of int
        ``(nw, ng, np)``: NLP variables, constraint rows, parameters.
    options : dict
        Checked HPIPM options (:func:`ocp_qp_options`).
    prefix : str
        Prefix of the C symbols.
    """

    def __init__(
        self, library: Path, sizes: tuple[int, int, int], options: dict[str, Any], prefix: str = ""
    ) -> None:
        self._args = (library, sizes, dict(options), prefix)
        self.library = ctypes.CDLL(str(verify_library(library)))
        nw, ng, np_ = sizes
        pointer, integer, real = ctypes.c_void_p, ctypes.c_int, ctypes.c_double

        def bind(name: str, restype: Any, *argtypes: Any) -> Any:
            function = getattr(self.library, f"{prefix}{name}")
            function.restype, function.argtypes = restype, list(argtypes)
            return function

        create = bind("uuv_rti_create", pointer, pointer)
        free = bind("uuv_rti_free", None, pointer)
        self._prepare = bind("uuv_rti_prepare", integer, pointer, pointer, pointer)
        self._iterate = bind(
            "uuv_rti_iterate", integer, *[pointer] * 3, integer, integer, real, real, real, *[pointer] * 3
        )
        self._seed = bind("uuv_rti_seed", None, *[pointer] * 4)
        self._resident_step = bind(
            "uuv_rti_resident_step", integer, pointer, pointer, integer, real, real, integer, *[pointer] * 4
        )
        #: ``uuv_rti_closed_loop_step(memory, settings, window)`` (:class:`ClosedLoopSettings`)
        self.closed_loop_step = bind("uuv_rti_closed_loop_step", integer, pointer, pointer, pointer)
        #: a mark of whose point the resident warm start is (:meth:`seed`'s ``owner``;
        #: ``RtiSolver.resident_step`` sets it to the primal of the plan that left it there)
        self.owner: object | None = None
        self._create, self._free = create, free
        self._settings = np.array(_options_array(options), dtype=float)
        self.memory = ctypes.c_void_p()
        self._finalizer: weakref.finalize | None = None
        self.reset()
        # preallocated buffers: a call copies its inputs in and hands C their addresses; the
        # outputs are views of one array, so that a caller keeps them with one copy (outputs)
        self.p = np.zeros(np_)
        #: ``[w, lam_x, lam_g, info]`` of the last call, one array (:attr:`w` ... are its views)
        self.outputs = np.zeros(2 * nw + ng + INFO_SIZE)
        self.w, self.lam_x, self.lam_g, self.info = self.split(self.outputs)
        self._pointers = [a.ctypes.data for a in (self.w, self.p, self.lam_x, self.lam_g, self.info)]

    def split(self, outputs: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Return views ``(w, lam_x, lam_g, info)`` of an array laid out as :attr:`outputs` (a copy of it)."""
        nw, ng = self._args[1][0], self._args[1][1]
        return outputs[:nw], outputs[nw : 2 * nw], outputs[2 * nw : 2 * nw + ng], outputs[2 * nw + ng :]

    def reset(self) -> None:
        """Replace the C memory (HPIPM's workspaces, the resident warm start) by a fresh one.

        A QP with a non-finite datum (a linearisation at a diverged point) leaves NaN in HPIPM's
        workspace, and every later QP of this memory came out non-finite too (a controller stuck
        on its fallback after a diverged run, reset or not): the step is then as just built.
        """
        memory = self._create(self._settings.ctypes.data)
        if not memory:
            raise MemoryError("uuv_rti_create: out of memory")
        if self._finalizer is not None:
            self._finalizer()  # frees the old memory now, once
        self.memory = ctypes.c_void_p(memory)
        self._finalizer = weakref.finalize(self, self._free, self.memory)
        self.owner = None

    def __reduce__(self) -> tuple[type[OcpQpStep], tuple[Any, ...]]:
        """Rebuild from the library (a copy gets HPIPM memory of its own)."""
        return (OcpQpStep, self._args)

    def prepare(self, w: np.ndarray, p: np.ndarray) -> None:
        """Linearise at ``w`` for the instance ``p`` and keep the QP (the state of ``p`` a guess)."""
        self.w[:] = w
        self.p[:] = p
        if self._prepare(self.memory, self._pointers[0], self._pointers[1]):
            raise RuntimeError("uuv_rti_prepare: the linearisation failed")

    def iterate(
        self,
        w: np.ndarray,
        p: np.ndarray,
        lam_x: np.ndarray,
        lam_g: np.ndarray,
        prepared: bool,
        max_iter: int,
        tol: float,
        qp_tolerance: float,
        budget: float,
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Gauss–Newton steps from ``w`` (see ``uuv_rti_iterate``); copies of w, λx, λg, info.

        ``info``: iterations, linearised violation, last ``‖d‖∞``, stop code (``STOP_*``), QP
        iterations of the last QP, HPIPM's status, seconds linearising and in QPs, seconds of the
        preparation used (0: none), all on the C step's own clock, and the number of QPs of the
        call that HPIPM did not solve in its mode and solved again in ``robust`` mode (its
        iterations counted in the QP iterations).
        ``budget`` in seconds (``inf``: none).
        """
        self.w[:] = w
        self.p[:] = p
        self.lam_x[:] = lam_x
        self.lam_g[:] = lam_g
        a = self._pointers
        self._iterate(
            self.memory, a[0], a[1], int(prepared), max_iter, tol, qp_tolerance, budget, a[2], a[3], a[4]
        )
        outputs = self.w.copy(), self.lam_x.copy(), self.lam_g.copy(), self.info.copy()
        self._drop_non_finite()
        return outputs

    def seed(self, w: np.ndarray, lam_x: np.ndarray, lam_g: np.ndarray, owner: object) -> None:
        """Keep ``w`` and the multipliers (this step's convention) as the resident warm start.

        ``owner`` marks whose warm start it is: a caller that finds another owner seeds again.
        """
        arrays = [np.ascontiguousarray(a, dtype=float) for a in (w, lam_x, lam_g)]
        if [a.size for a in arrays] != [self.w.size, self.lam_x.size, self.lam_g.size]:
            raise ValueError(
                f"seed needs w and lam_x of size {self.w.size} and lam_g of size {self.lam_g.size}, "
                f"got sizes {[a.size for a in arrays]}"
            )
        self._seed(self.memory, *(a.ctypes.data for a in arrays))
        self.owner = owner

    def resident_step(
        self, p: np.ndarray, max_iter: int, tol: float, qp_tolerance: float, converged_only: bool
    ) -> bool:
        """Gauss–Newton steps from the resident warm start (see ``uuv_rti_resident_step``).

        ``True`` when the step is accepted: :attr:`w`, :attr:`lam_x`, :attr:`lam_g` then hold the
        new point (buffers overwritten by the next call: copy what you keep) and the resident
        warm start is that point shifted.  ``False`` leaves both unchanged.  :attr:`info` as
        :meth:`iterate`, in either case.
        """
        self.p[:] = p
        a = self._pointers
        code = self._resident_step(
            self.memory, a[1], max_iter, tol, qp_tolerance, int(converged_only), a[0], a[2], a[3], a[4]
        )
        if code != 0:
            self._drop_non_finite()
        return code == 0

    def _drop_non_finite(self) -> None:
        """Reset the C memory after a call whose QP solution was not finite (see :meth:`reset`)."""
        # info[1], the linearised violation, is inf exactly when the QP solution (or the
        # linearisation) was not finite: HPIPM's workspace may hold NaN from then on
        if not math.isfinite(float(self.info[1])):
            self.reset()


def build_step(
    data: NlpData,
    state_dim: int,
    x0_param: np.ndarray,
    objective_scale: float,
    still_water_slice: slice | None,
    options: dict[str, Any],
    directory: Path,
    name: str,
) -> OcpQpStep:
    """Generate, compile (cached) and load the C step of one NLP variant.

    Raises
    ------
    UnsupportedStructure
        The NLP does not fit HPIPM's OCP-QP (see :func:`ocp_qp_layout`).
    uuv_ocp.native.compile.CodegenError
        No compiler, a failed build, or a library that does not match its checksum.
    """
    layout = ocp_qp_layout(data, state_dim)
    function, offsets = stage_data_function(data, layout, objective_scale, still_water_slice, f"{name}_data")
    source = c_source(layout, function, offsets, x0_param, data)
    library = compile_functions(
        [function],
        directory,
        name=name,
        extra_source=source,
        extra_header=C_HEADER,
        link=hpipm_link_flags(),
        flags=("-O1", "-fPIC", "-shared"),
    )
    assert library.path is not None
    options = resolve_equality_first(options, layout, data)
    return OcpQpStep(library.path, (data.lbx.size, data.lbg.size, int(data.nlp["p"].numel())), options)


def _options_array(options: dict[str, Any]) -> list[float]:
    """HPIPM options in the order ``uuv_rti_create`` reads them.

    The QP solver's settings, the partial condensing horizon, ``loose_first_qp``, the first
    QP's settings (``loose_settings``, with the same ``iter_max`` and warm start), then
    ``equality_first`` and ``eliminate_x0``.
    """

    def settings(source: dict[str, Any]) -> list[float]:
        tolerances = [float(source[f"tol_{kind}"]) for kind in ("stat", "eq", "ineq", "comp")]
        mode = float(HPIPM_MODES.index(source["mode"]))
        return [mode, float(options["iter_max"]), *tolerances, float(options["warm_start"])]

    return [
        *settings(options),
        float(options["cond_horizon"]),
        float(options["loose_first_qp"]),
        *settings(options["loose_settings"]),
        float(options["equality_first"]),
        float(options["eliminate_x0"]),
    ]


def _sparsity(name: str, rows: int) -> str:
    """CasADi's compressed-column sparsity of a dense column of ``rows`` entries."""
    entries = [rows, 1, 0, rows, *range(rows)]
    return f"static const casadi_int {name}[{len(entries)}] = {{{', '.join(map(str, entries))}}};\n"


#: declarations of the generated ``nmpc_step`` (CasADi's external-function ABI), for the header
NMPC_HEADER = """
int nmpc_step(const casadi_real** arg, casadi_real** res, casadi_int* iw, casadi_real* w, int mem);
int nmpc_step_work(casadi_int* sz_arg, casadi_int* sz_res, casadi_int* sz_iw, casadi_int* sz_w);
casadi_int nmpc_step_n_in(void);
casadi_int nmpc_step_n_out(void);
const casadi_int* nmpc_step_sparsity_in(casadi_int i);
const casadi_int* nmpc_step_sparsity_out(casadi_int i);
const char* nmpc_step_name_in(casadi_int i);
const char* nmpc_step_name_out(casadi_int i);
"""


def nmpc_step_source(
    data: NlpData,
    state_dim: int,
    x0_param: np.ndarray,
    u_prev_param: np.ndarray,
    control_scale: np.ndarray,
    control_centre: np.ndarray,
    objective_scale: float,
    options: dict[str, Any],
    prefix: str = "",
) -> tuple[str, ca.Function, str]:
    """C of ``nmpc_step(x0, u_prev, p, w) -> (u, w_next, violation)`` on HPIPM's OCP-QP.

    One real-time iteration of ``data`` (the step always taken, its linearised violation
    returned, ``inf`` if not finite), ``u`` the first control in physical units
    (``z · control_scale + control_centre``), ``w_next`` the new primal shifted one stage.
    The function follows CasADi's external-function ABI (loadable with ``casadi.external``,
    callable like CasADi-generated code); its HPIPM memory is allocated at the first call and
    kept (one instance per process: not reentrant).

    Returns
    -------
    source : str
        The C to append to the generated code of the stage-data function.
    function : casadi.Function
        The stage-data function (``nmpc_step_data``) the source calls, to be generated.
    header : str
        Declarations of the exported functions.
    """
    layout = ocp_qp_layout(data, state_dim)
    options = resolve_equality_first(options, layout, data)
    function, offsets = stage_data_function(data, layout, objective_scale, None, "nmpc_step_data")
    nw, np_ = data.lbx.size, int(data.nlp["p"].numel())
    nu = len(u_prev_param)
    step = c_source(layout, function, offsets, x0_param, data, prefix=prefix)
    control = np.asarray(data.control_index[0], dtype=int)
    wrapper = (
        "/* ---- nmpc_step(x0, u_prev, p, w) -> (u, w_next, violation): CasADi's external ABI ---- */\n"
        f"#define NMPC_NX {state_dim}\n#define NMPC_NU {nu}\n#define NMPC_NP {np_}\n"
        + _c_array("int", "nmpc_x0", x0_param)
        + _c_array("int", "nmpc_u_prev", u_prev_param)
        + _c_array("int", "nmpc_control", control)
        + _c_array("double", "nmpc_scale", control_scale)
        + _c_array("double", "nmpc_centre", control_centre)
        + _c_array("double", "nmpc_options", _options_array(options))
        + _sparsity("nmpc_s_x0", state_dim)
        + _sparsity("nmpc_s_u", nu)
        + _sparsity("nmpc_s_p", np_)
        + _sparsity("nmpc_s_w", nw)
        + _sparsity("nmpc_s_1", 1)
        + _NMPC_WRAPPER
    )
    header = C_HEADER + NMPC_HEADER
    if prefix:
        wrapper = wrapper.replace("uuv_rti_", f"{prefix}uuv_rti_").replace("nmpc_step", f"{prefix}nmpc_step")
        header = header.replace("uuv_rti_", f"{prefix}uuv_rti_").replace("nmpc_step", f"{prefix}nmpc_step")
    return step + wrapper, function, header


_NMPC_WRAPPER = r"""
static void* nmpc_memory = 0;
static double nmpc_p[NMPC_NP > 0 ? NMPC_NP : 1], nmpc_w[RTI_NW], nmpc_lam_x[RTI_NW];
static double nmpc_lam_g[RTI_NG > 0 ? RTI_NG : 1], nmpc_info[10];

int nmpc_step(const casadi_real** arg, casadi_real** res, casadi_int* iw, casadi_real* w, int mem) {
  int i;
  (void)iw; (void)w; (void)mem;
  if (!nmpc_memory) {
    nmpc_memory = uuv_rti_create(nmpc_options); /* HPIPM's memory: once per process */
    if (!nmpc_memory) return 1;
  }
  for (i = 0; i < NMPC_NP; ++i) nmpc_p[i] = arg[2] ? arg[2][i] : 0.0;
  for (i = 0; i < NMPC_NX; ++i) nmpc_p[nmpc_x0[i]] = arg[0] ? arg[0][i] : 0.0;
  for (i = 0; i < NMPC_NU; ++i) nmpc_p[nmpc_u_prev[i]] = arg[1] ? arg[1][i] : 0.0;
  for (i = 0; i < RTI_NW; ++i) nmpc_w[i] = arg[3] ? arg[3][i] : 0.0;
  /* one step, always taken (qp_tol = inf): the caller judges it by the violation */
  uuv_rti_iterate(nmpc_memory, nmpc_w, nmpc_p, 0, 1, 0.0, INFINITY, INFINITY, nmpc_lam_x, nmpc_lam_g,
                  nmpc_info);
  if (res[0])
    for (i = 0; i < NMPC_NU; ++i) res[0][i] = nmpc_w[nmpc_control[i]] * nmpc_scale[i] + nmpc_centre[i];
  if (res[1])
    for (i = 0; i < RTI_NW; ++i) res[1][i] = nmpc_w[rti_primal_shift[i]];
  if (res[2]) res[2][0] = isfinite(nmpc_info[1]) ? nmpc_info[1] : INFINITY;
  return 0;
}

int nmpc_step_work(casadi_int* sz_arg, casadi_int* sz_res, casadi_int* sz_iw, casadi_int* sz_w) {
  if (sz_arg) *sz_arg = 4;
  if (sz_res) *sz_res = 3;
  if (sz_iw) *sz_iw = 0;
  if (sz_w) *sz_w = 0;
  return 0;
}

casadi_int nmpc_step_n_in(void) { return 4; }
casadi_int nmpc_step_n_out(void) { return 3; }

const casadi_int* nmpc_step_sparsity_in(casadi_int i) {
  switch (i) {
    case 0: return nmpc_s_x0;
    case 1: return nmpc_s_u;
    case 2: return nmpc_s_p;
    case 3: return nmpc_s_w;
    default: return 0;
  }
}

const casadi_int* nmpc_step_sparsity_out(casadi_int i) {
  switch (i) {
    case 0: return nmpc_s_u;
    case 1: return nmpc_s_w;
    case 2: return nmpc_s_1;
    default: return 0;
  }
}

const char* nmpc_step_name_in(casadi_int i) {
  static const char* names[4] = {"x0", "u_prev", "p", "w"};
  return i >= 0 && i < 4 ? names[i] : 0;
}

const char* nmpc_step_name_out(casadi_int i) {
  static const char* names[3] = {"u", "w_next", "violation"};
  return i >= 0 && i < 3 ? names[i] : 0;
}
"""
