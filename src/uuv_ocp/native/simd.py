"""Lane-vectorised C for evaluating one SX Function over a population (SIMD across candidates).

CasADi's ``Function.map`` generates a loop that evaluates the one-candidate code once per
candidate.  :func:`batch_kernel_source` instead walks the SX algorithm of the one-candidate
function (``instruction_id`` / ``instruction_input`` / ``instruction_output``) and emits each
operation once for ``UUV_LANES`` candidates at a time, on the vector type of
``simd_math.h`` (GCC/clang vector extensions: 8 doubles with AVX-512, 4 with AVX, 2 with
SSE2, so build with ``-march=native``; with 8 lanes a remainder of at most 4 candidates runs
on a 4-lane copy of the same code).  Operations that depend only on the shared inputs
(the problem parameters ``p``) are hoisted out of the candidate loop and computed once, as
scalars.

Arithmetic (+ − × ÷, |·|, min/max, squares) is IEEE-identical to the scalar code; ``sin`` and
``cos`` use fdlibm's polynomial kernels (a few ulp from libm) and are paired into one
``sincos`` when both appear for the same argument; rarer operations fall back to libm lane by
lane.  The generated symbol follows CasADi's external-function ABI, with its metadata
(sparsities, names) delegated to a CasADi-generated twin in the same file, so
``casadi.external`` loads it like any generated function.
"""

from __future__ import annotations

from pathlib import Path

import casadi as ca

__all__ = ["SIMD_MATH", "UnsupportedOperation", "batch_kernel_source"]

SIMD_MATH = Path(__file__).with_name("simd_math.h")
"""The vector-arithmetic header inlined in front of every kernel."""


class UnsupportedOperation(NotImplementedError):
    """The function contains an operation the lane-wise emitter does not know."""


def _op(name: str) -> int:
    return int(getattr(ca, f"OP_{name}"))


# operations with a native vector form: C expression on operand names a, b
_NATIVE = {
    _op("ASSIGN"): "{a}",
    _op("ADD"): "{a} + {b}",
    _op("SUB"): "{a} - {b}",
    _op("MUL"): "{a} * {b}",
    _op("DIV"): "{a} / {b}",
    _op("NEG"): "-{a}",
    _op("SQ"): "{a} * {a}",
    _op("TWICE"): "2.0 * {a}",
    _op("INV"): "1.0 / {a}",
}
# scalar C of every supported operation (the scalar prelude, and the lane-wise fallback)
_SCALAR = {
    **_NATIVE,
    _op("FABS"): "fabs({a})",
    _op("FMAX"): "fmax({a}, {b})",
    _op("FMIN"): "fmin({a}, {b})",
    _op("SIN"): "sin({a})",
    _op("COS"): "cos({a})",
    _op("EXP"): "exp({a})",
    _op("LOG"): "log({a})",
    _op("POW"): "pow({a}, {b})",
    _op("CONSTPOW"): "pow({a}, {b})",
    _op("SQRT"): "sqrt({a})",
    _op("TAN"): "tan({a})",
    _op("ASIN"): "asin({a})",
    _op("ACOS"): "acos({a})",
    _op("ATAN"): "atan({a})",
    _op("ATAN2"): "atan2({a}, {b})",
    _op("SINH"): "sinh({a})",
    _op("COSH"): "cosh({a})",
    _op("TANH"): "tanh({a})",
    _op("ASINH"): "asinh({a})",
    _op("ACOSH"): "acosh({a})",
    _op("ATANH"): "atanh({a})",
    _op("ERF"): "erf({a})",
    _op("LOG1P"): "log1p({a})",
    _op("EXPM1"): "expm1({a})",
    _op("HYPOT"): "hypot({a}, {b})",
    _op("FLOOR"): "floor({a})",
    _op("CEIL"): "ceil({a})",
    _op("FMOD"): "fmod({a}, {b})",
    _op("COPYSIGN"): "copysign({a}, {b})",
    _op("SIGN"): "({a} < 0 ? -1.0 : {a} > 0 ? 1.0 : {a})",
    _op("LT"): "(double)({a} < {b})",
    _op("LE"): "(double)({a} <= {b})",
    _op("EQ"): "(double)({a} == {b})",
    _op("NE"): "(double)({a} != {b})",
    _op("NOT"): "(double)(!{a})",
    _op("AND"): "(double)({a} && {b})",
    _op("OR"): "(double)({a} || {b})",
    _op("IF_ELSE_ZERO"): "({a} == 0 ? 0.0 : {b})",
}
_VECTOR_CALL = {
    _op("FABS"): "uuv_fabs({a})",
    _op("FMAX"): "uuv_fmax({a}, {b})",
    _op("FMIN"): "uuv_fmin({a}, {b})",
}
_SIN, _COS = _op("SIN"), _op("COS")
_CONST, _INPUT, _OUTPUT = _op("CONST"), _op("INPUT"), _op("OUTPUT")
_NAMES = {int(getattr(ca, n)): n[3:] for n in dir(ca) if n.startswith("OP_")}


def batch_kernel_source(function: ca.Function, name: str, population: int, reference: str) -> str:
    """C source of ``name``: ``function`` evaluated for ``population`` candidates, SIMD.

    Parameters
    ----------
    function : casadi.Function
        One-candidate SX function.  Input 0 is the candidate (a dense column); the other inputs
        are shared by all candidates; every output is a dense column.
    name : str
        C symbol of the batched function.  Its inputs: input 0 as a ``(n0 × population)``
        matrix (column ``c`` = candidate ``c``), the shared inputs unchanged; its outputs:
        ``(m × population)``.
    population : int
        Number of candidates (columns).
    reference : str
        Name of a CasADi-generated function with the same signature in the same C file (the
        mapped ``function``): the metadata entry points (sparsity, names) delegate to it.

    Raises
    ------
    UnsupportedOperation
        If ``function`` is not an SX function or uses an operation without a C form here.
    """
    if not function.is_a("SXFunction"):
        raise UnsupportedOperation(f"{function.name()!r} is not an SX function")
    if not function.sparsity_in(0).is_dense() or function.size2_in(0) != 1:
        raise UnsupportedOperation("input 0 (the candidate) must be a dense column")
    for index in range(function.n_out()):
        if not function.sparsity_out(index).is_dense() or function.size2_out(index) != 1:
            raise UnsupportedOperation(f"output {index} must be a dense column")
    body = _Emitter(function).emit()
    header = SIMD_MATH.read_text()
    candidate_size = function.nnz_in(0)
    outputs = "\n".join(
        f"      if (res[{o}]) for (l = 0; l < UUV_LANES && c0 + l < last; ++l) "
        f"res[{o}][(size_t)(c0 + l) * {function.nnz_out(o)} + {nz}] = ({value})[l];"
        for o, nz, value in body.outputs
    )
    metadata = _delegated_metadata(name, reference, function.n_in(), function.n_out())
    passes = f"""
#if defined(__GNUC__) && !defined(__clang__) && !defined(UUV_DEFAULT_SCHEDULE)
/* GCC: schedule before register allocation, minding the pressure: the long straight-line body
 * spills less (~7 % faster on the s2 kernel, measured 2026-12-06); the arithmetic is unchanged */
__attribute__((optimize("schedule-insns", "sched-pressure")))
#endif
static void {name}_PASS(const casadi_real** arg, casadi_real** res, int first, int last) {{
  uuv_vd lanes[{candidate_size}];
  int c0, l, j;
{_indent(body.scalar, 2)}
  for (c0 = first; c0 < last; c0 += UUV_LANES) {{
    for (l = 0; l < UUV_LANES; ++l) {{
      const size_t c = (size_t)(c0 + l < last ? c0 + l : last - 1);
      const casadi_real* candidate = arg[0] ? arg[0] + c * {candidate_size} : 0;
      for (j = 0; j < {candidate_size}; ++j) lanes[j][l] = candidate ? candidate[j] : 0.0;
    }}
    {{
{_indent(body.vector, 6)}
{outputs}
    }}
  }}
}}
"""
    renames = _NARROW_NAMES
    narrow_on = "\n".join(f"#define {n} {n}_narrow" for n in renames)
    narrow_off = "\n".join(f"#undef {n}" for n in renames)
    return f"""
/* ---- {name}: {function.name()} over {population} candidates, {{UUV_LANES}} lanes at a time ---- */
{header}
{passes.replace("_PASS(", "_wide(")}
#if UUV_LANES == 8
/* A remainder of at most 4 candidates runs on 4-lane vectors: the same source and arithmetic
 * (every lane's value depends only on its candidate), ~8.5 % off a 20-candidate call (2 x 8 + 4
 * instead of 3 x 8, measured 2026-12-06): the 512-bit operations and divisions cost more. */
{narrow_on}
#undef UUV_LANES
#define UUV_LANES 4
#ifndef UUV_OCP_SIMD_MATH_NARROW
#define UUV_OCP_SIMD_MATH_NARROW
#undef UUV_OCP_SIMD_MATH_H
{header}
#endif
{passes.replace("_PASS(", "_narrow(")}
{narrow_off}
#undef UUV_LANES
#define UUV_LANES 8
#endif
CASADI_SYMBOL_EXPORT int {name}(const casadi_real** arg, casadi_real** res, casadi_int* iw,
                                casadi_real* w, int mem) {{
  (void)iw; (void)w; (void)mem;
#if UUV_LANES == 8
  if ({population} % 8 != 0 && {population} % 8 <= 4) {{
    if ({population} >= 8) {name}_wide(arg, res, 0, {population} - {population} % 8);
    {name}_narrow(arg, res, {population} - {population} % 8, {population});
    return 0;
  }}
#endif
  {name}_wide(arg, res, 0, {population});
  return 0;
}}
{metadata}
"""


#: the vector types and helpers of simd_math.h, renamed for its 4-lane copy (the kernels' tail)
_NARROW_NAMES = (
    "uuv_vd",
    "uuv_vl",
    "uuv_any",
    "uuv_bcast",
    "uuv_select",
    "uuv_fabs",
    "uuv_fmax",
    "uuv_fmin",
    "uuv_kernel_sin",
    "uuv_kernel_cos",
    "uuv_sincos",
    "uuv_sin",
    "uuv_cos",
)


def _indent(lines: list[str], spaces: int) -> str:
    return "\n".join(" " * spaces + line for line in lines)


def _delegated_metadata(name: str, reference: str, n_in: int, n_out: int) -> str:
    export = "CASADI_SYMBOL_EXPORT"
    return f"""
{export} int {name}_checkout(void) {{ return 0; }}
{export} void {name}_release(int mem) {{ (void)mem; }}
{export} void {name}_incref(void) {{}}
{export} void {name}_decref(void) {{}}
{export} casadi_int {name}_n_in(void) {{ return {n_in}; }}
{export} casadi_int {name}_n_out(void) {{ return {n_out}; }}
{export} casadi_real {name}_default_in(casadi_int i) {{ return {reference}_default_in(i); }}
{export} const char* {name}_name_in(casadi_int i) {{ return {reference}_name_in(i); }}
{export} const char* {name}_name_out(casadi_int i) {{ return {reference}_name_out(i); }}
{export} const casadi_int* {name}_sparsity_in(casadi_int i) {{ return {reference}_sparsity_in(i); }}
{export} const casadi_int* {name}_sparsity_out(casadi_int i) {{ return {reference}_sparsity_out(i); }}
{export} int {name}_work(casadi_int* sz_arg, casadi_int* sz_res, casadi_int* sz_iw, casadi_int* sz_w) {{
  if (sz_arg) *sz_arg = {n_in};
  if (sz_res) *sz_res = {n_out};
  if (sz_iw) *sz_iw = 0;
  if (sz_w) *sz_w = 0;
  return 0;
}}
"""


class _Body:
    def __init__(self) -> None:
        self.scalar: list[str] = []
        self.vector: list[str] = []
        self.outputs: list[tuple[int, int, str]] = []


class _Emitter:
    """One pass over the SX algorithm: SSA names, scalar/vector classification, C lines."""

    def __init__(self, function: ca.Function) -> None:
        self.function = function
        self.slot_name: dict[int, str] = {}
        self.is_vector: dict[str, bool] = {}
        self.trig: dict[str, dict[int, str]] = {}

    def _operands(self, k: int) -> list[str]:
        return [self.slot_name[slot] for slot in self.function.instruction_input(k)]

    def _paired_trig(self) -> set[int]:
        """Instructions whose sin/cos has a cos/sin partner on the same value (one sincos).

        A work slot is reused, so a value is identified by (slot, how often it was written).
        """
        ops_of: dict[tuple[int, int], dict[int, int]] = {}
        writes: dict[int, int] = {}
        f = self.function
        for k in range(f.n_instructions()):
            op = f.instruction_id(k)
            if op in (_SIN, _COS):
                (slot,) = f.instruction_input(k)
                ops_of.setdefault((slot, writes.get(slot, 0)), {})[op] = k
            if op != _OUTPUT:
                for slot in f.instruction_output(k):
                    writes[slot] = writes.get(slot, 0) + 1
        return {k for ops in ops_of.values() if len(ops) == 2 for k in ops.values()}

    def emit(self) -> _Body:
        f = self.function
        body = _Body()
        paired = self._paired_trig()
        for k in range(f.n_instructions()):
            op = f.instruction_id(k)
            if op == _OUTPUT:
                (slot,) = f.instruction_input(k)
                output, nz = f.instruction_output(k)
                value = self.slot_name[slot]
                if not self.is_vector[value]:
                    value = f"uuv_bcast({value})"
                body.outputs.append((output, nz, value))
                continue
            if op == ca.OP_CALL:  # e.g. collocation's Newton solve: CasADi's own C evaluates it
                raise UnsupportedOperation("a call to another Function has no SIMD C form here")
            (slot,) = f.instruction_output(k)
            if op == _CONST:
                name = f"s{k}"
                body.scalar.append(f"const double {name} = {float(f.instruction_constant(k))!r};")
                vector = False
            elif op == _INPUT:
                source, nz = f.instruction_input(k)
                vector = source == 0
                name = f"{'v' if vector else 's'}{k}"
                if vector:
                    body.vector.append(f"const uuv_vd {name} = lanes[{nz}];")
                else:
                    body.scalar.append(f"const double {name} = arg[{source}] ? arg[{source}][{nz}] : 0.0;")
            else:
                if op not in _SCALAR:
                    raise UnsupportedOperation(f"operation {_NAMES.get(op, op)} has no SIMD C form here")
                operands = self._operands(k)
                vector = any(self.is_vector[a] for a in operands)
                if not vector:
                    name = f"s{k}"
                    body.scalar.append(f"const double {name} = {self._scalar(op, operands)};")
                elif op in (_SIN, _COS):
                    name = self._trig(op, operands[0], k in paired, body.vector)
                else:
                    name = f"v{k}"
                    body.vector.extend(self._vector(op, operands, name))
            self.slot_name[slot] = name
            self.is_vector[name] = vector
        return body

    @staticmethod
    def _scalar(op: int, operands: list[str]) -> str:
        a, b = (operands + [""])[:2]
        return _SCALAR[op].format(a=a, b=b)

    def _vector(self, op: int, operands: list[str], name: str) -> list[str]:
        if op in _NATIVE:
            a, b = (operands + [""])[:2]
            return [f"const uuv_vd {name} = {_NATIVE[op].format(a=a, b=b)};"]
        as_vector = [a if self.is_vector[a] else f"uuv_bcast({a})" for a in operands]
        if op in _VECTOR_CALL:
            a, b = (as_vector + [""])[:2]
            return [f"const uuv_vd {name} = {_VECTOR_CALL[op].format(a=a, b=b)};"]
        # lane by lane through libm: exact, slower
        lanes = [f"({a})[l]" for a in as_vector]
        a, b = (lanes + [""])[:2]
        return [
            f"uuv_vd {name};",
            f"for (l = 0; l < UUV_LANES; ++l) {name}[l] = {_SCALAR[op].format(a=a, b=b)};",
        ]

    def _trig(self, op: int, argument: str, paired: bool, lines: list[str]) -> str:
        cached = self.trig.setdefault(argument, {})
        if op in cached:
            return cached[op]
        if paired:
            sine, cosine = f"{argument}_sin", f"{argument}_cos"
            lines.append(f"uuv_vd {sine}, {cosine};")
            lines.append(f"uuv_sincos({argument}, &{sine}, &{cosine});")
            cached.update({_SIN: sine, _COS: cosine})
            return cached[op]
        name = f"{argument}_{'sin' if op == _SIN else 'cos'}"
        lines.append(f"const uuv_vd {name} = uuv_{'sin' if op == _SIN else 'cos'}({argument});")
        cached[op] = name
        return name
