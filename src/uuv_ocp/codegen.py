"""C code generation of any problem (Ocp or tracking preset): generate, compile, load back, verify.

``generate_c(problem, directory)`` writes one C file (CasADi ``CodeGenerator``) holding

* ``cost(U, p) -> (objective, penalty)``: the condensed cost of the problem,
* ``cost_batch(U[3N × population], p) -> fitness[1 × population]``: the swarm fitness of a
  population, as a SIMD kernel (:mod:`uuv_ocp.native.simd`: one operation for 8 candidates
  at a time with AVX-512; sin/cos within a few ulp of libm), and ``cost_batch_exact``, CasADi's
  mapped code of the same fitness (bit-identical to the virtual machine),
* ``dynamics(x, tau, current) -> xdot`` and ``model_step(x, tau, current) -> x_next``,
* ``rollout(U, p) -> X`` and ``score_terms(U, p)``: the predicted states and what
  :func:`uuv_ocp.score` judges,
* ``uuv_ocp_igwo(...)`` / ``uuv_ocp_igwo_pcg64(...)``: the whole IGWO step of the paper as a C
  loop around ``cost_batch``, its random draws given or drawn in C from numpy's PCG64 state
  (the same numbers, so the same seed gives the same result as the Python IGWO),

compiles it with the system C compiler into a shared library, loads the CasADi functions back
with ``casadi.external`` and checks every one against its symbolic twin on random inputs.
Builds are cached by a SHA-256 of the generated source, the compiler and its flags: a closed
loop or a campaign compiles once.

Compiler: ``$CC`` if set, else the first of ``cc``, ``gcc``, ``clang`` on ``PATH``.  Without one
:class:`CompilerNotFoundError` names what was looked for; the solvers' ``compiled=True`` path
then warns once and falls back to CasADi's virtual machine.
"""

from __future__ import annotations

import ctypes
import os
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import casadi as ca
import numpy as np

from uuv_ocp.build import Transcribed
from uuv_ocp.native.compile import (
    DEFAULT_FLAGS as CORE_FLAGS,
)
from uuv_ocp.native.compile import (
    CompilationError,
    CompilerNotFoundError,
    VerificationError,
    compile_functions,
    find_c_compiler,
)
from uuv_ocp.native.simd import UnsupportedOperation, batch_kernel_source

#: ``-ffp-contract=off`` keeps compiled arithmetic identical to CasADi's virtual machine;
#: ``-march=native`` gives the SIMD kernel this processor's vector width (3x on AVX-512,
#: measured) and makes the processor part of the cache key; ``-D_GNU_SOURCE`` lets the IGWO
#: step place its random-number thread on another CPU (Linux).
DEFAULT_FLAGS = (*CORE_FLAGS, "-ffp-contract=off", "-march=native", "-D_GNU_SOURCE")
FUNCTION_NAMES = ("cost", "cost_batch", "dynamics", "model_step", "rollout", "score_terms")
#: generated along with ``cost_batch``: CasADi's own (scalar, mapped) code of the same fitness
EXACT_BATCH = "cost_batch_exact"
_IGWO_SOURCE = Path(__file__).parent / "native" / "igwo_step.c"

__all__ = [
    "CompilationError",
    "CompilerNotFoundError",
    "GeneratedCode",
    "NativeIgwo",
    "VerificationError",
    "compiled_build",
    "uses_pcg64",
    "find_c_compiler",
    "generate_c",
    "symbolic_functions",
]


@dataclass(frozen=True)
class GeneratedCode:
    """What :func:`generate_c` produced.

    Parameters
    ----------
    directory : Path
        Folder of the sources and the library.
    source, header : Path
        Generated C source and header.
    library : Path or None
        The compiled shared library (``None`` with ``compile=False``).
    functions : dict
        Name -> ``casadi.Function`` loaded from the library (empty with ``compile=False``);
        with ``cost_batch`` comes ``cost_batch_exact``.
    max_error : dict
        Name -> largest relative difference compiled vs symbolic found by the verification.
    population : int
        Population size ``cost_batch`` and the IGWO step are built for.
    digest : str
        SHA-256 of source + compiler + flags (the cache key).
    reused : bool
        Whether an existing library was reused from the cache.
    simd : bool
        Whether ``cost_batch`` is the SIMD kernel (else CasADi's mapped code: the problem's cost
        has an operation the kernel emitter does not support).
    """

    directory: Path
    source: Path
    header: Path
    library: Path | None
    functions: dict = field(default_factory=dict)
    max_error: dict = field(default_factory=dict)
    population: int = 20
    digest: str = ""
    reused: bool = False
    simd: bool = False

    def __getitem__(self, name: str) -> ca.Function:
        """Return the loaded Function ``name`` (``KeyError`` if it was not generated)."""
        return self.functions[name]


def symbolic_functions(problem: Transcribed, population: int = 20) -> dict[str, ca.Function]:
    """Build the problem's Functions that :func:`generate_c` emits, by name."""
    from uuv_ocp.solvers.swarm import batched_fitness

    built = problem.build()
    batch = batched_fitness(problem, population)
    return {
        "cost": built.cost,
        "cost_batch": _renamed(batch, "cost_batch"),
        EXACT_BATCH: _renamed(batch, EXACT_BATCH),
        "dynamics": _renamed(built.spec.dynamics, "dynamics"),
        "model_step": _renamed(built.step, "model_step"),
        "rollout": built.rollout,
        "score_terms": built.score_terms,
    }


def _batch_sources(problem: Transcribed, population: int) -> tuple[str, bool]:
    """C of the SIMD ``cost_batch`` (or ``""`` if unsupported) and whether it is SIMD."""
    from uuv_ocp.solvers.swarm import candidate_fitness

    try:
        kernel = batch_kernel_source(candidate_fitness(problem), "cost_batch", population, EXACT_BATCH)
    except UnsupportedOperation:
        return "", False
    return kernel, True


def _renamed(function: ca.Function, name: str) -> ca.Function:
    symbols = [ca.MX.sym(function.name_in(i), function.sparsity_in(i)) for i in range(function.n_in())]
    outputs = function.call(symbols)
    return ca.Function(
        name,
        symbols,
        outputs,
        [function.name_in(i) for i in range(function.n_in())],
        [function.name_out(i) for i in range(function.n_out())],
    )


def generate_c(
    problem: Transcribed,
    directory: str | Path,
    *,
    functions: tuple[str, ...] = FUNCTION_NAMES,
    population: int = 20,
    compile: bool = True,
    verify: bool = True,
    flags: tuple[str, ...] = DEFAULT_FLAGS,
    seed: int = 0,
    tolerance: float = 1e-12,
) -> GeneratedCode:
    """Generate C for ``problem``, compile it, load it back and verify it.

    Parameters
    ----------
    problem : Ocp or TrackingProblem
    directory : str or Path
        Output folder (created).
    functions : tuple of str
        Any of ``"cost"``, ``"cost_batch"``, ``"dynamics"``, ``"model_step"``, ``"rollout"``,
        ``"score_terms"`` (what :func:`uuv_ocp.score` evaluates); the IGWO step is
        added whenever ``"cost_batch"`` is present.
    population : int
        Population size of ``cost_batch`` and the IGWO step (>= 1; the IGWO needs >= 4).
    compile : bool
        Compile and load (otherwise only write the sources).
    verify : bool
        Compare every compiled function with its symbolic twin on random inputs.
    flags : tuple of str
        Compiler flags (``-ffp-contract=off`` keeps arithmetic identical to the virtual machine,
        ``-march=native`` sets the SIMD width).
    seed : int
        Seed of the verification inputs.
    tolerance : float
        Largest accepted relative difference in the verification.
    """
    unknown = sorted(set(functions) - set(FUNCTION_NAMES))
    if unknown or not functions:
        raise ValueError(f"functions must be a non-empty subset of {list(FUNCTION_NAMES)}, got {functions!r}")
    if isinstance(population, bool) or not isinstance(population, int) or population < 1:
        raise ValueError(f"population must be an integer >= 1, got {population!r}")
    directory = Path(directory)
    symbolic = symbolic_functions(problem, population)
    chosen = [symbolic[name] for name in FUNCTION_NAMES if name in functions]
    external = []
    extra = ""
    simd = False
    if "cost_batch" in functions:
        kernel, simd = _batch_sources(problem, population)
        if simd:  # CasADi's mapped code becomes cost_batch_exact; cost_batch is the kernel
            chosen = [symbolic[EXACT_BATCH] if f.name() == "cost_batch" else f for f in chosen]
            external = [symbolic["cost_batch"]]
        extra = kernel + _IGWO_SOURCE.read_text()
    existing = set(directory.glob("*.so")) if directory.exists() else set()

    def build(build_flags: tuple[str, ...]):
        return compile_functions(
            chosen,
            directory,
            compile=compile,
            verify=verify,
            rng=np.random.default_rng(seed),
            flags=build_flags,
            tolerance=tolerance,
            extra_source=extra,
            external=external,
        )

    try:
        library = build(flags)
    except CompilationError:
        portable = tuple(flag for flag in flags if not flag.endswith("=native"))
        if portable == tuple(flags):
            raise
        library = build(portable)  # a compiler that rejects -march=native: portable SIMD width
    return GeneratedCode(
        directory=directory,
        source=library.source,
        header=library.header,
        library=library.path,
        functions=library.functions,
        max_error=library.max_error,
        population=population,
        digest=library.digest,
        reused=library.path in existing,
        simd=simd,
    )


# ------------------------------------------------------------------ cached build for solvers
def default_cache_directory() -> Path:
    """``$UUV_OCP_CACHE`` or ``~/.cache/uuv_ocp``: where solver builds are kept."""
    return Path(os.environ.get("UUV_OCP_CACHE", Path.home() / ".cache" / "uuv_ocp"))


def compiled_build(problem: Transcribed, population: int) -> GeneratedCode | None:
    """Build (once per problem and population) what the solvers' ``compiled=True`` runs on.

    Returns the compiled ``cost_batch`` + IGWO step, ``rollout`` and ``score_terms`` of
    ``problem``, or ``None`` with one warning when no compiler works.
    """
    cache = problem._store.setdefault("codegen", {})
    if population not in cache:
        try:
            cache[population] = generate_c(
                problem,
                default_cache_directory(),
                functions=("cost_batch", "rollout", "score_terms"),
                population=population,
            )
        except (CompilerNotFoundError, CompilationError) as error:
            warnings.warn(
                f"compiled=True unavailable ({error}); using CasADi's virtual machine instead",
                RuntimeWarning,
                stacklevel=3,
            )
            cache[population] = None
    return cache[population]


class NativeIgwo:
    """The all-C IGWO step of a compiled build, called through ``ctypes``.

    ``run(p, offset, lower, upper, positions, draws, a, w, c1, c2)`` mirrors the Python IGWO
    (``solvers/swarm.py``) operation by operation (bit-identical when the Python IGWO runs on
    the same compiled ``cost_batch``; to the SIMD kernel's sin/cos rounding against the virtual
    machine); ``draws`` is either the array
    ``(iterations, 8, population, dim)`` of uniform numbers or a ``numpy.random.Generator``
    on PCG64 (numpy's default), from which the C code draws exactly the numbers
    ``draws.random((iterations, 8, population, dim))`` would give, and advances it as that
    call would, on a second thread one iteration ahead when ``rng_thread`` (the same numbers:
    the 288 k uniform draws of a 20 × 30 step then cost no time on the step's own thread).
    Inputs are float64 arrays.
    """

    def __init__(self, build: GeneratedCode) -> None:
        self.build = build
        self.library = ctypes.CDLL(str(build.library))
        pointer = ctypes.POINTER(ctypes.c_double)
        tail: list[Any] = [ctypes.c_double, ctypes.c_double, *[ctypes.c_int] * 3, *[pointer] * 4]
        self._given = self.library.uuv_ocp_igwo
        self._given.argtypes = [pointer] * 8 + tail
        self._drawing = self.library.uuv_ocp_igwo_pcg64
        words: list[Any] = [ctypes.POINTER(ctypes.c_uint64), ctypes.c_int]
        self._drawing.argtypes = [*[pointer] * 5, *words, *[pointer] * 2, *tail]
        for function in (self._given, self._drawing):
            function.restype = ctypes.c_int
        self.random = self.library.uuv_ocp_pcg64_random
        self.random.argtypes = [ctypes.c_uint64] * 4 + [pointer, ctypes.c_size_t]
        self.random.restype = None

    def run(
        self,
        p: np.ndarray,
        offset: np.ndarray,
        lower: np.ndarray,
        upper: np.ndarray,
        positions: np.ndarray,
        draws: np.ndarray | np.random.Generator,
        a: np.ndarray,
        w: np.ndarray,
        c1: float = 0.5,
        c2: float = 0.5,
        rng_thread: bool | int = True,
    ) -> dict:
        """One IGWO run; returns ``x``, ``fun``, ``history``, ``population``.

        ``rng_thread``: draw on a second thread (``True``), or not; ``2`` starts the thread
        but never waits for it, as the step does for a block its worker is late with (the
        numbers are the same in every case).  ``late_blocks`` in the result counts the
        iterations whose numbers the step drew itself because the second thread was late.
        """
        population, dim = positions.shape
        iterations = a.shape[0]
        pointer = ctypes.POINTER(ctypes.c_double)

        def data(array: np.ndarray) -> ctypes._Pointer:
            return array.ctypes.data_as(pointer)

        inputs = [np.ascontiguousarray(v, dtype=float) for v in (p, offset, lower, upper, positions)]
        schedules = [np.ascontiguousarray(v, dtype=float) for v in (a, w)]
        best_x, best_f = np.empty(dim), np.empty(1)
        history, final = np.empty(iterations + 1), np.empty((population, dim))
        tail = (c1, c2, population, dim, iterations, *map(data, (best_x, best_f, history, final)))
        late_blocks = 0
        if isinstance(draws, np.random.Generator):
            if not uses_pcg64(draws):
                raise ValueError(f"draws must use PCG64, got {type(draws.bit_generator).__name__}")
            state = draws.bit_generator.state
            words = (ctypes.c_uint64 * 5)(*_split(state["state"]["state"]), *_split(state["state"]["inc"]), 0)
            status = self._drawing(*map(data, inputs), words, int(rng_thread), *map(data, schedules), *tail)
            if status == 0:  # a failed run leaves the Generator untouched
                state["state"]["state"] = (words[0] << 64) | words[1]
                draws.bit_generator.state = state
                late_blocks = int(words[4])
        else:
            block = np.ascontiguousarray(draws, dtype=float)
            status = self._given(*map(data, inputs), data(block), *map(data, schedules), *tail)
        if status != 0:
            reason = "the fitness evaluation failed" if status == 1 else "out of memory"
            raise RuntimeError(f"uuv_ocp_igwo returned status {status}: {reason}")
        return {
            "x": best_x,
            "fun": float(best_f[0]),
            "history": history,
            "population": final,
            "late_blocks": late_blocks,
        }


def uses_pcg64(generator: np.random.Generator) -> bool:
    """Whether ``generator`` runs on numpy's PCG64, the stream the C step reproduces."""
    return type(generator.bit_generator) is np.random.PCG64


def _split(value: int) -> tuple[int, int]:
    return value >> 64, value & 0xFFFFFFFFFFFFFFFF
