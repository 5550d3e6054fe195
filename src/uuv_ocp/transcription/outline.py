"""Outlined NLP: the unrolled SX NLP rewritten as MX calls of one CasADi Function per stage structure.

The multiple-shooting NLP (:mod:`uuv_ocp.transcription.multiple_shooting`) is fully unrolled SX:
its generated C grows with the horizon (BlueROV2 survey, N = 20: 26.7 MB, ``nlp_hess_l`` 750 k
lines; docs/benchmarks.md, "Compiled fatrop").  :func:`outline` splits it by stage instead:

1. every constraint row and every additive term of the objective goes to the smallest stage
   among the decision variables it depends on (structural dependence, exact for SX); rows and
   terms on no staged variable go to the :data:`REST` stage;
2. each stage's rows, unstaged rows (see ``row_stages``) and terms are three parts; each part
   becomes an SX Function ``(w, q) -> (rows, cost)`` of the variables ``w`` and
   parameters ``q`` it reads (in their NLP order), on uniformly named symbols;
3. parts whose Functions serialize to the same text (the same instruction list, constants and
   sparsities: an exact structural equality) share one Function, which the MX NLP calls once
   per stage; ``g`` is reassembled in the original row order and ``f`` is the sum of the costs.

The MX NLP has the same ``x``, ``p``, bounds, row order and Jacobian/Hessian sparsity as the SX
one, so fatrop's structure detection, the bounds and the multipliers see the same problem; its
code generation emits each shared Function (and the derivatives AD makes of it) once plus one
call per stage.  It must be handed to ``nlpsol`` with ``expand=False`` (expanding re-inlines it).
"""

from __future__ import annotations

import hashlib
from collections.abc import Sequence
from dataclasses import dataclass

import casadi as ca
import numpy as np

__all__ = ["OutlineError", "Outlined", "check_outlined", "outline"]

#: the part of rows and terms that depend on no staged variable (parameters only, or only
#: unstaged variables such as the terminal slacks)
REST = -1


class OutlineError(RuntimeError):
    """The outlined NLP does not reproduce the SX NLP (a grouping or reassembly error)."""


@dataclass(frozen=True)
class _Part:
    """One stage's rows and objective terms as an SX Function on its own variables and parameters."""

    stage: int
    function: ca.Function
    serialized: str
    variables: list[int]
    parameters: list[int]
    rows: list[int]


@dataclass(frozen=True)
class Outlined:
    """The outlined NLP and how it was grouped.

    Parameters
    ----------
    nlp : dict
        ``x``, ``p``, ``f``, ``g`` as MX (the SX NLP's sizes and row order).
    groups : tuple of (casadi.Function, tuple of int)
        Each shared stage Function and the stages that call it (:data:`REST`: the rest part).
    """

    nlp: dict[str, ca.MX]
    groups: tuple[tuple[ca.Function, tuple[int, ...]], ...]


def additive_terms(expression: ca.SX) -> list[ca.SX]:
    """Split a scalar SX into terms whose sum it is, through ``+``, ``−``, negation and constant factors.

    Iterative (an objective's sum is a chain as long as the horizon's residual count).  A
    constant factor ``c`` is moved onto each term (``c·(a + b) -> c·a + c·b``): the solvers scale
    the objective, which would otherwise keep the whole sum in one term.
    """
    terms: list[ca.SX] = []
    stack: list[tuple[ca.SX, float]] = [(expression, 1.0)]
    while stack:
        node, factor = stack.pop()
        if node.is_op(ca.OP_ADD):
            stack += [(node.dep(1), factor), (node.dep(0), factor)]
        elif node.is_op(ca.OP_SUB):
            stack += [(node.dep(1), -factor), (node.dep(0), factor)]
        elif node.is_op(ca.OP_NEG):
            stack.append((node.dep(0), -factor))
        elif node.is_op(ca.OP_MUL) and node.dep(0).is_constant():
            stack.append((node.dep(1), factor * float(node.dep(0))))
        elif node.is_op(ca.OP_MUL) and node.dep(1).is_constant():
            stack.append((node.dep(0), factor * float(node.dep(1))))
        elif not (node.is_constant() and float(node) == 0.0):
            terms.append(node if factor == 1.0 else factor * node)
    return terms


def _columns(expression: ca.SX, symbols: ca.SX) -> list[np.ndarray]:
    """Per entry of ``expression``: the indices of ``symbols`` it depends on (structurally)."""
    rows, columns = ca.jacobian_sparsity(expression, symbols).get_triplet()
    found: list[list[int]] = [[] for _ in range(expression.numel())]
    for row, column in zip(rows, columns, strict=True):
        found[row].append(column)
    return [np.array(entry, dtype=int) for entry in found]


def _group_key(part: _Part) -> str:
    """Hash of a part's serialized Function: equal keys are checked again in full by :func:`_checked`."""
    return hashlib.sha256(part.serialized.encode()).hexdigest()


def _checked(shared: _Part, member: _Part) -> None:
    """Refuse ``member`` in ``shared``'s group unless their Functions are the same algorithm."""
    same_sizes = len(shared.variables) == len(member.variables) and len(shared.parameters) == len(
        member.parameters
    )
    if not same_sizes or shared.serialized != member.serialized:
        raise OutlineError(
            f"stage {member.stage} was grouped with stage {shared.stage} but its Function differs "
            f"({len(member.variables)} variables, {member.function.n_instructions()} instructions "
            f"vs {len(shared.variables)}, {shared.function.n_instructions()})"
        )


def _part(stage: int, nlp: dict[str, ca.SX], rows: list[int], terms: list[ca.SX], reads: tuple) -> _Part:
    """Return the SX Function of one stage's ``rows`` of ``g`` and objective ``terms``."""
    variables = sorted(set().union(*reads[0])) if reads[0] else []
    parameters = sorted(set().union(*reads[1])) if reads[1] else []
    x, p, g = nlp["x"], nlp["p"], nlp["g"]
    own_x = ca.vertcat(*[x[i] for i in variables]) if variables else ca.SX(0, 1)
    own_p = ca.vertcat(*[p[i] for i in parameters]) if parameters else ca.SX(0, 1)
    values = ca.vertcat(*[g[i] for i in rows]) if rows else ca.SX(0, 1)
    cost = ca.SX(0)
    for term in terms:
        cost += term
    named = ca.Function("stage", [own_x, own_p], [values, cost])
    # the same names in every stage: the serialization then differs only where the algorithm does
    w, q = ca.SX.sym("w", len(variables)), ca.SX.sym("q", len(parameters))
    function = ca.Function("stage", [w, q], named.call([w, q]), ["w", "q"], ["g", "f"])
    return _Part(stage, function, function.serialize(), variables, parameters, rows)


def outline(
    nlp: dict[str, ca.SX], stages: Sequence[int | None], row_stages: Sequence[int | None] | None = None
) -> Outlined:
    """Rewrite an SX NLP as MX calls of one shared Function per distinct stage structure.

    Parameters
    ----------
    nlp : dict
        ``x``, ``p``, ``f``, ``g`` (SX; ``x`` and ``p`` purely symbolic vectors).
    stages : sequence of int or None
        The stage of each entry of ``x`` (``None``: not staged, e.g. a terminal slack), as in
        :attr:`~uuv_ocp.transcription.multiple_shooting.NlpData.variable_keys`.
    row_stages : sequence of int or None, optional
        The stage of each row of ``g`` as its key has it (``constraint_keys``).  Rows keyed
        ``None`` (the initial-state rows, the terminal ones) then form a part of their own
        instead of joining their stage's: the first and last stages keep the middle stages'
        Function (one shared Function instead of three of the same size, half the C).

    Returns
    -------
    Outlined
        The MX NLP and its groups.

    Raises
    ------
    ValueError
        ``nlp`` is not SX with ``x``, ``p``, ``f``, ``g``, or ``stages`` has not one entry per variable.
    OutlineError
        Two stages grouped together do not have the same Function (see :func:`_checked`).
    """
    if not isinstance(nlp, dict) or not all(isinstance(nlp.get(key), ca.SX) for key in ("x", "p", "f", "g")):
        raise ValueError(
            f"nlp must be a dict of SX x, p, f, g, got keys {sorted(nlp) if isinstance(nlp, dict) else nlp}"
        )
    x, p, f, g = nlp["x"], nlp["p"], nlp["f"], nlp["g"]
    if len(stages) != x.numel():
        raise ValueError(f"stages must have one entry per variable ({x.numel()}), got {len(stages)}")
    if row_stages is not None and len(row_stages) != g.numel():
        raise ValueError(f"row_stages must have one entry per row of g ({g.numel()}), got {len(row_stages)}")
    unstaged = [False] * g.numel() if row_stages is None else [s is None for s in row_stages]
    stage = np.array([REST if s is None else int(s) for s in stages], dtype=int)
    terms = additive_terms(f)
    objective = ca.vertcat(*terms) if terms else ca.SX(0, 1)
    row_x, row_p = _columns(g, x), _columns(g, p)
    term_x, term_p = _columns(objective, x), _columns(objective, p)

    def owner(columns: np.ndarray) -> int:
        staged = stage[columns][stage[columns] != REST]
        return int(staged.min()) if staged.size else REST

    # per stage three parts: its rows, its unstaged rows, its objective terms.  The costs apart
    # from the rows let the first stage (no tracking cost) share the others' rows Function,
    # which holds the expensive part (the RK4 step and its derivatives)
    members: dict[tuple[int, int], tuple[list[int], list[int]]] = {}
    for i in range(g.numel()):
        members.setdefault((owner(row_x[i]), int(unstaged[i])), ([], []))[0].append(i)
    for j in range(len(terms)):
        members.setdefault((owner(term_x[j]), 2), ([], []))[1].append(j)
    parts = []
    for (k, _), (rows, own_terms) in sorted(members.items()):
        reads = (
            [set(row_x[i]) for i in rows] + [set(term_x[j]) for j in own_terms],
            [set(row_p[i]) for i in rows] + [set(term_p[j]) for j in own_terms],
        )
        parts.append(_part(k, nlp, rows, [terms[j] for j in own_terms], reads))
    return _assembled(parts, x.numel(), p.numel(), g.numel())


def _assembled(parts: list[_Part], nx: int, np_: int, ng: int) -> Outlined:
    """Return the MX NLP calling one shared Function per group of ``parts``."""
    shared: dict[str, _Part] = {}
    callers: dict[str, list[int]] = {}
    x, p = ca.MX.sym("x", nx), ca.MX.sym("p", np_)
    pieces, order, cost = [], [], ca.MX(0)
    for part in parts:
        key = _group_key(part)
        first = shared.setdefault(key, part)
        _checked(first, part)
        callers.setdefault(key, []).append(part.stage)
        values, term = first.function(x[part.variables], p[part.parameters])
        pieces.append(values)
        order += part.rows
        cost += term
    if sorted(order) != list(range(ng)):
        raise OutlineError(f"the stages' rows are not a permutation of g's {ng} rows")
    position = np.empty(ng, dtype=int)
    position[np.array(order, dtype=int)] = np.arange(ng)
    g = ca.vertcat(*pieces)[position.tolist()] if ng else ca.MX(0, 1)
    groups = tuple((shared[key].function, tuple(callers[key])) for key in shared)
    return Outlined({"x": x, "p": p, "f": cost, "g": g}, groups)


def check_outlined(
    nlp: dict[str, ca.SX],
    outlined: dict[str, ca.MX],
    rng: np.random.Generator,
    points: int = 2,
    tolerance: float = 1e-12,
) -> float:
    """Compare ``f`` and ``g`` of the outlined and the SX NLP at random points; return the largest error.

    Errors are relative, ``|a − b| / (1 + |a|)``; ``x`` and ``p`` are standard normal.

    Raises
    ------
    OutlineError
        An error above ``tolerance`` (or a NaN in one NLP where the other has a number).
    """
    reference = ca.Function("reference", [nlp["x"], nlp["p"]], [nlp["f"], nlp["g"]])
    candidate = ca.Function("candidate", [outlined["x"], outlined["p"]], [outlined["f"], outlined["g"]])
    largest = 0.0
    for _ in range(points):
        x = rng.standard_normal(nlp["x"].numel())
        p = rng.standard_normal(nlp["p"].numel())
        for name, expected, found in zip(("f", "g"), reference(x, p), candidate(x, p), strict=True):
            a, b = np.array(expected, dtype=float).ravel(), np.array(found, dtype=float).ravel()
            if not np.array_equal(np.isnan(a), np.isnan(b)):
                raise OutlineError(
                    f"the outlined NLP's {name} is NaN where the SX NLP's is not (or the reverse)"
                )
            same = (a == b) | np.isnan(a)  # equal infinities too
            error = np.abs(a[~same] - b[~same]) / (1.0 + np.abs(a[~same]))
            error[np.isnan(error)] = np.inf  # an infinity against a number
            largest = max(largest, float(error.max()) if error.size else 0.0)
    if largest > tolerance:
        raise OutlineError(
            f"the outlined NLP differs from the SX NLP by {largest:.3g} (tolerance {tolerance:g})"
        )
    return largest
