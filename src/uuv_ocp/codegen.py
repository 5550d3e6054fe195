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

Trust: a library is loaded only after its bytes matched the SHA-256 its build recorded and its
ELF headers were found complete, only if it and its sidecar are files of the current user that
others cannot write (no symbolic links), and only from a folder owned by the current user and
not writable by others; every file written gets mode ``0600`` (see
:mod:`uuv_ocp.native.compile`).  The solvers' cache (:func:`default_cache_directory`) is
created with mode ``0700``; an unusable cache (unsafe, not writable) is handled like a missing
compiler by ``compiled=True``: one warning, then the virtual machine.
"""

from __future__ import annotations

import contextlib
import ctypes
import dataclasses
import hashlib
import math
import numbers
import os
import re
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import casadi as ca
import numpy as np

from uuv_ocp import _validation as check
from uuv_ocp._concurrency import BuildCache, serialised
from uuv_ocp.build import Transcribed
from uuv_ocp.judge import instance_parameters
from uuv_ocp.native.compile import (
    DEFAULT_FLAGS as CORE_FLAGS,
)
from uuv_ocp.native.compile import (
    BuildDirectoryError,
    CodegenError,
    CompilationError,
    CompilerNotFoundError,
    IntegrityError,
    VerificationError,
    compile_functions,
    find_c_compiler,
    jit_workspace,
    verify_library,
)
from uuv_ocp.native.simd import UnsupportedOperation, batch_kernel_source

#: ``-ffp-contract=off`` keeps compiled arithmetic identical to CasADi's virtual machine;
#: Verification tolerance of the SIMD ``cost_batch`` (relative): its own ``sin``/``cos`` differ
#: from libm by a few ulp (native/simd_math.h), and the cost of an N-step rollout amplifies that;
#: measured 2.7e-12 on the BlueROV2 obstacle course, where 1e-12 refused the kernel.  Everything
#: else (CasADi's generated code, the exact batch) keeps ``tolerance``.
SIMD_TOLERANCE = 1e-10
#: ``-march=native`` gives the SIMD kernel this processor's vector width (3x on AVX-512,
#: measured) and makes the processor part of the cache key; ``-D_GNU_SOURCE`` lets the IGWO
#: step place its random-number thread on another CPU (Linux).
DEFAULT_FLAGS = (*CORE_FLAGS, "-ffp-contract=off", "-march=native", "-D_GNU_SOURCE")
FUNCTION_NAMES = ("cost", "cost_batch", "dynamics", "model_step", "rollout", "score_terms")
#: generated on request only: the exact NMPC step (one real-time iteration on HPIPM)
NMPC_STEP = "nmpc_step"
ACCEPTED_NAMES = (*FUNCTION_NAMES, NMPC_STEP)
#: random states on which the generated ``nmpc_step`` is checked against the Python backend
NMPC_CHECK_STATES = 100
NMPC_TOLERANCE = 1e-9
#: Agreement (fraction of the control range) of the generated ``nmpc_step`` with the same step on
#: CasADi's conic HPIPM interface: a second QP solver on the full-space QP, equal to the two QP
#: solvers' tolerances rather than to rounding.  Measured on the 100 cold QPs of the check
#: (N = 20): 7.6e-8 on s2, 1.1e-7 on s5, 1.3e-8 on s1 and on the BlueROV2 survey.  It was 1e-4
#: while the C step took the last iterate of a QP HPIPM's ``speed`` mode did not solve as its
#: solution (1.2e-4 off on s2 with the wheel's HPIPM, 3.8e-5 with a native build; now solved
#: again in ``robust`` mode, see native/rti_hpipm.c); a wrong stage mapping moves the control by
#: a sizeable part of its range.
NMPC_CONIC_TOLERANCE = 1e-5
#: generated along with ``cost_batch``: CasADi's own (scalar, mapped) code of the same fitness
EXACT_BATCH = "cost_batch_exact"
#: smallest population of the IGWO step (three leaders and at least one other wolf)
MIN_IGWO_POPULATION = 4
_IGWO_SOURCE = Path(__file__).parent / "native" / "igwo_step.c"
#: declarations of the IGWO step's exported functions, added to the generated header
IGWO_HEADER = """
#include <stddef.h>
#include <stdint.h>
int uuv_ocp_igwo(const double* p, const double* offset, const double* lower, const double* upper,
                 const double* positions0, const double* draws, const double* a_schedule,
                 const double* w_schedule, double c1, double c2, int n, int dim, int iterations,
                 double* best_x, double* best_f, double* history, double* final_positions);
int uuv_ocp_igwo_pcg64(const double* p, const double* offset, const double* lower,
                       const double* upper, const double* positions0, uint64_t* pcg, int rng_thread,
                       const double* a_schedule, const double* w_schedule, double c1, double c2,
                       int n, int dim, int iterations, double* best_x, double* best_f,
                       double* history, double* final_positions);
void uuv_ocp_pcg64_random(uint64_t state_hi, uint64_t state_lo, uint64_t inc_hi, uint64_t inc_lo,
                          double* out, size_t count);
"""

__all__ = [
    "BuildDirectoryError",
    "CompilationError",
    "CompilerNotFoundError",
    "GeneratedCode",
    "IntegrityError",
    "NativeIgwo",
    "VerificationError",
    "compiled_build",
    "default_cache_directory",
    "jit_directory",
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
        Name -> largest relative difference compiled vs symbolic found by the verification
        (``nmpc_step``: against the Python backend, and ``nmpc_step_conic``: against the same
        step on CasADi's conic HPIPM interface, as fractions of the control range).
    population : int
        Population size ``cost_batch`` and the IGWO step are built for.
    digest : str
        SHA-256 of source + compiler + flags (the cache key).
    reused : bool
        Whether an existing library was reused from the cache.
    simd : bool
        Whether ``cost_batch`` is the SIMD kernel (else CasADi's mapped code: the problem's cost
        has an operation the kernel emitter does not support).
    nmpc_library : Path or None
        The library of ``nmpc_step`` (``uuv_ocp_nmpc_<digest>.so``, linked to the HPIPM and
        BLASFEO libraries of the CasADi wheel), when requested and compiled.
    prefix : str
        What every exported C symbol starts with (see :func:`generate_c`).
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
    nmpc_library: Path | None = None
    prefix: str = ""

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


def _batch_sources(problem: Transcribed, population: int, prefix: str = "") -> tuple[str, bool]:
    """C of the SIMD ``cost_batch`` (or ``""`` if unsupported) and whether it is SIMD."""
    from uuv_ocp.solvers.swarm import candidate_fitness

    try:
        kernel = batch_kernel_source(
            candidate_fitness(problem), f"{prefix}cost_batch", population, f"{prefix}{EXACT_BATCH}"
        )
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


@serialised
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
    prefix: str = "",
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
        Population size of ``cost_batch`` and the IGWO step (>= 4 with ``"cost_batch"``, which
        brings the IGWO step; else >= 1).
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
        Largest accepted relative difference in the verification (>= 0).
    prefix : str
        Start of every exported C symbol and of the file names: ``""`` (default: ``cost``,
        ``uuv_ocp_igwo``, ``uuv_ocp_gen.h``, …), a C identifier such as ``"s2_"``
        (``s2_cost``, ``s2_uuv_ocp_igwo``, ``s2_uuv_ocp_gen.h``), or ``"auto"``: ``"p"`` and
        the first 12 hex digits of the problem's content key and ``"_"``.  Libraries of
        different prefixes link into one program; the loaded ``functions`` keep the plain names.

    Raises
    ------
    TypeError
        ``problem`` is not an Ocp or a preset, ``directory`` is not a path.
    ValueError
        Any other argument out of its domain (the message names it).
    BuildDirectoryError
        ``directory`` is owned by another user, writable by its group or others, not writable
        or not a directory (see :func:`uuv_ocp.native.compile.secure_directory`).
    """
    if not isinstance(problem, Transcribed):
        raise TypeError(
            "problem must be an Ocp or a TrackingProblem, got "
            f"{type(problem).__name__}: {check.shown(problem)}"
        )
    if not isinstance(directory, str | os.PathLike):
        raise TypeError(f"directory must be a path (str or os.PathLike), got {type(directory).__name__}")
    if isinstance(functions, str) or not isinstance(functions, tuple | list):
        raise ValueError(
            f"functions must be a tuple of names from {list(FUNCTION_NAMES)}, got {check.shown(functions)}"
        )
    unknown = [name for name in functions if name not in ACCEPTED_NAMES]
    if unknown or not functions:
        raise ValueError(
            f"functions must be a non-empty subset of {list(ACCEPTED_NAMES)}, got {check.shown(functions)}"
        )
    minimum = MIN_IGWO_POPULATION if "cost_batch" in functions else 1
    population = check.positive_int("population", population, minimum)
    check.boolean("compile", compile)
    check.boolean("verify", verify)
    if isinstance(flags, str) or not all(isinstance(flag, str) for flag in flags):
        raise ValueError(f"flags must be a tuple of strings, got {check.shown(flags)}")
    if isinstance(seed, bool) or not isinstance(seed, numbers.Integral) or seed < 0:
        raise ValueError(f"seed must be an integer >= 0, got {check.shown(seed)}")
    tolerance = check.nonnegative_float("tolerance", tolerance)
    prefix = _prefix(problem, prefix)
    directory = Path(directory)
    symbolic = symbolic_functions(problem, population)
    chosen = [symbolic[name] for name in FUNCTION_NAMES if name in functions]
    external = []
    extra = header = ""
    simd = False
    if "cost_batch" in functions:
        kernel, simd = _batch_sources(problem, population, prefix)
        if simd:  # CasADi's mapped code becomes cost_batch_exact; cost_batch is the kernel
            chosen = [symbolic[EXACT_BATCH] if f.name() == "cost_batch" else f for f in chosen]
            external = [symbolic["cost_batch"]]
        extra = kernel + _prefixed(_IGWO_SOURCE.read_text(), prefix)
        header = _prefixed(IGWO_HEADER, prefix)

    def build(build_flags: tuple[str, ...]):
        return compile_functions(
            chosen,
            directory,
            compile=compile,
            verify=verify,
            rng=np.random.default_rng(seed),
            flags=build_flags,
            tolerance=tolerance,
            tolerances={"cost_batch": max(tolerance, SIMD_TOLERANCE)} if simd else None,
            extra_source=extra,
            external=external,
            extra_header=header,
            name=f"{prefix}uuv_ocp_gen",
            prefix=prefix,
        )

    nmpc = None
    if NMPC_STEP in functions:
        nmpc = _nmpc_build(problem, directory, compile, verify, seed, flags, prefix)
    if not chosen:  # only the NMPC step was asked for
        assert nmpc is not None
        return GeneratedCode(
            directory=directory,
            source=nmpc.source,
            header=nmpc.header,
            library=nmpc.path,
            functions=dict(nmpc.functions),
            max_error=dict(nmpc.max_error),
            population=population,
            digest=nmpc.digest,
            reused=nmpc.reused,
            nmpc_library=nmpc.path,
            prefix=prefix,
        )
    try:
        library = build(flags)
    except CompilationError:
        portable = tuple(flag for flag in flags if not flag.endswith("=native"))
        if portable == tuple(flags):
            raise
        library = build(portable)  # a compiler that rejects -march=native: portable SIMD width
    loaded, errors = dict(library.functions), dict(library.max_error)
    if nmpc is not None:
        loaded.update(nmpc.functions)
        errors.update(nmpc.max_error)
    return GeneratedCode(
        directory=directory,
        source=library.source,
        header=library.header,
        library=library.path,
        functions=loaded,
        max_error=errors,
        population=population,
        digest=library.digest,
        reused=library.reused,
        simd=simd,
        nmpc_library=None if nmpc is None else nmpc.path,
        prefix=prefix,
    )


_EXPORTED = re.compile(r"\b(cost_batch\w*|uuv_ocp_igwo|uuv_ocp_igwo_pcg64|uuv_ocp_pcg64_random)\b")


def _prefixed(source: str, prefix: str) -> str:
    """Hand-written C (IGWO step, its declarations) with its exported names prefixed."""
    return _EXPORTED.sub(lambda match: prefix + match.group(1), source) if prefix else source


def _prefix(problem: Transcribed, prefix: object) -> str:
    """Validate ``prefix`` (``""``, a C identifier, or ``"auto"``: derived from the content key)."""
    if prefix == "auto":
        return f"p{hashlib.sha256(str(problem.spec().key).encode()).hexdigest()[:12]}_"
    if not isinstance(prefix, str) or (prefix and not re.fullmatch(r"[A-Za-z_][A-Za-z0-9_]*", prefix)):
        raise ValueError(
            f"prefix must be '', 'auto' or a C identifier such as 's2_', got {check.shown(prefix)}"
        )
    return prefix


def hpipm_link_flags() -> tuple[str, ...]:
    """Compiler and linker arguments for C that calls HPIPM.

    The native build for this CPU (:mod:`uuv_ocp.native.hpipm`, static and hidden inside the
    library) when one is installed, intact (every folder and file of it checked, see
    :func:`uuv_ocp.native.hpipm.installed`) and not refused by ``UUV_OCP_HPIPM=wheel``; else the
    CasADi wheel's own copy: it ships ``libhpipm`` and ``libblasfeo`` next to CasADi's libraries
    and their headers in ``casadi/include``, and the library records that folder as its
    run-time search path (an absolute path, so programs linked to it run from any directory).
    """
    from uuv_ocp.native.hpipm import old_partial_condensing, selected

    native = selected()
    if native is not None:
        flags = native.link_flags()
        include = native.directory / "include" / "hpipm"
    else:
        folder = Path(ca.__file__).resolve().parent
        include = folder / "include"
        flags = (
            f"-I{include}",
            f"-L{folder}",
            "-Wl,--no-as-needed",
            "-lhpipm",
            "-lblasfeo",
            f"-Wl,-rpath,{folder}",
        )
    return (*flags, "-DUUV_HPIPM_OLD_PART_COND") if old_partial_condensing(include) else flags


def _nmpc_build(
    problem: Transcribed, directory: Path, compile: bool, verify: bool, seed: int, flags, prefix: str
):
    """Compile ``nmpc_step`` into its own library and check it against the Python backend.

    The C step is the one of ``sqp-rti`` with ``qpsol="hpipm-ocp"`` (stage data generated by
    CasADi, HPIPM's OCP-QP API, see :mod:`uuv_ocp.solvers.rti_ocp`) behind CasADi's
    external-function ABI, so programs and ``casadi.external`` call it as before.
    """
    from uuv_ocp.solvers.rti import nmpc_step_function
    from uuv_ocp.solvers.rti_ocp import nmpc_step_source

    function, backend = nmpc_step_function(problem)
    variant = "soft" if "soft" in backend.variants else "hard"
    spec = problem.spec()
    layout = spec.layout
    positions = np.arange(layout.size)
    source, data_function, header = nmpc_step_source(
        backend.variants[variant],
        spec.state_dim,
        positions[layout.x0],
        positions[layout.u_prev],
        np.asarray(spec.control_scale, dtype=float),
        np.broadcast_to(np.asarray(spec.control_centre, dtype=float), (spec.control_size,)),
        backend.objective_scale,
        backend.ocp_qp_options,
        prefix,
    )
    core_flags = tuple(flag for flag in flags if flag in CORE_FLAGS or flag.startswith("-O"))
    library = compile_functions(
        [data_function],
        directory,
        name=f"{prefix}uuv_ocp_nmpc",
        prefix=prefix,
        compile=compile,
        verify=False,  # random inputs in [-1, 1] are no QP instances: checked below instead
        flags=core_flags or CORE_FLAGS,
        extra_source=source,
        external=[function],  # defined by the C above; this is its symbolic twin
        extra_header=header,
        link=hpipm_link_flags(),
    )
    if compile and verify:
        # against the backend's own C step (the glue: parameters, scaling, shift, ABI) to rounding,
        # and against the conic HPIPM path on the full-space QP (the stage mapping) to the QP
        # solvers' tolerances: the same C step on both sides would hide a mapping error
        _, conic = nmpc_step_function(problem, qpsol="hpipm")
        for reference, tolerance, what in (
            (backend, NMPC_TOLERANCE, "the Python sqp-rti backend"),
            (conic, NMPC_CONIC_TOLERANCE, "sqp-rti on CasADi's conic HPIPM interface"),
        ):
            error = check_nmpc_step(
                problem, library.functions[NMPC_STEP], reference, np.random.default_rng(seed)
            )
            if not error <= tolerance:
                raise VerificationError(
                    f"compiled nmpc_step disagrees with {what}: max error {error:.3e} "
                    f"(fraction of the control range) > {tolerance:g}"
                )
            if reference is backend:
                library = dataclasses.replace(library, max_error={NMPC_STEP: error})
            else:
                library = dataclasses.replace(
                    library, max_error={**library.max_error, "nmpc_step_conic": error}
                )
    return library


def check_nmpc_step(
    problem: Transcribed,
    compiled: ca.Function,
    backend: Any,
    rng: np.random.Generator,
    states: int = NMPC_CHECK_STATES,
) -> float:
    """Largest difference of the compiled ``nmpc_step`` control from the Python backend's.

    On ``states`` instances: the reference state at a random time plus Gaussian noise, a
    random last control inside the box, one real-time iteration from the cold guess (the
    backend of :func:`~uuv_ocp.solvers.rti.nmpc_step_function`, same NLP and QP solver).
    Returned as a fraction of each control's range (largest over the instances).
    """
    spec = problem.spec()
    variant = "soft" if "soft" in backend.variants else "hard"
    span = spec.upper - spec.lower
    worst = 0.0
    for _ in range(states):
        x0, t0 = _random_instance(problem, rng)
        u_prev = spec.lower + span * rng.uniform(0.25, 0.75, spec.control_size)
        p = instance_parameters(problem, x0, t0, u_prev=u_prev)
        guess_states, guess_controls = problem.initial_guess(p)
        w = backend.compose_primal(variant, guess_states, guess_controls, problem.previous_scaled(p))
        result = backend.solve(p, None)
        control, _, _ = compiled(x0, u_prev, p, w)
        if not result.success:
            return math.inf
        difference = np.abs(np.asarray(control).ravel() - result.controls[0]) / span
        worst = max(worst, float(np.max(difference)))
    return worst


def _random_instance(problem: Transcribed, rng: np.random.Generator) -> tuple[np.ndarray, float]:
    """Draw a state near the reference at a random time (tracking problems), or random (an Ocp)."""
    reference = getattr(problem, "reference", None)
    nx = problem.state_dim
    if reference is None:
        return rng.normal(0.0, 1.0, nx), 0.0
    t0 = float(rng.uniform(0.0, min(problem.latest_start(), 60.0)))  # type: ignore[attr-defined]
    state = np.asarray(reference.evaluate([t0])[0], dtype=float)
    return state + rng.normal(0.0, 0.05, nx), t0


# ------------------------------------------------------------------ cached build for solvers
def default_cache_directory() -> Path:
    """``$UUV_OCP_CACHE`` or ``~/.cache/uuv_ocp``: where solver builds are kept (absolute).

    An empty ``UUV_OCP_CACHE`` counts as unset; a relative one is taken relative to the current
    directory at the time of the call.  The folder is created with mode ``0700`` by the first
    build and must stay owned by the user and not writable by others.
    """
    configured = os.environ.get("UUV_OCP_CACHE", "").strip()
    folder = Path(configured) if configured else Path.home() / ".cache" / "uuv_ocp"
    return Path(os.path.abspath(folder))


def jit_directory() -> contextlib.AbstractContextManager[str]:
    """Context in which CasADi's JIT of the exact solvers builds inside the cache's ``jit/`` folder.

    Yields the folder (with a trailing separator) to pass as ``jit_options["directory"]``;
    see :func:`uuv_ocp.native.compile.jit_workspace` (the working directory is moved there
    while CasADi writes its sources, so nothing lands in the user's current directory).
    """
    return jit_workspace(default_cache_directory() / "jit")


def compiled_build(problem: Transcribed, population: int) -> GeneratedCode | None:
    """Build (once per problem content, population and cache folder) what ``compiled=True`` runs on.

    Returns the compiled ``cost_batch`` + IGWO step, ``rollout`` and ``score_terms`` of
    ``problem``, or ``None`` with one warning when the compiled path is unavailable: no
    compiler works, the compiled code fails its verification, or the cache folder cannot be
    used (unsafe or not writable: the warning names it and the fix).
    """
    directory = default_cache_directory()

    def build() -> GeneratedCode | None:
        try:
            return generate_c(
                problem, directory, functions=("cost_batch", "rollout", "score_terms"), population=population
            )
        except (CodegenError, OSError) as error:
            warnings.warn(
                f"compiled=True unavailable ({error}); using CasADi's virtual machine instead",
                RuntimeWarning,
                stacklevel=5,
            )
            return None

    # equal problems share a build: the key is the content, the population and the folder
    return _COMPILED_BUILDS.get((problem.spec().key, population, str(directory)), build)


#: :func:`compiled_build`'s builds by (problem content, population, cache folder); bounded.
_COMPILED_BUILDS: BuildCache[GeneratedCode | None] = BuildCache(32)


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
    Inputs are float64 arrays; every length and shape is checked against the build (the C code
    trusts them).

    Raises
    ------
    ValueError
        ``build`` has no compiled library with ``cost_batch`` (the IGWO step comes with it).
    IntegrityError, BuildDirectoryError
        The library's bytes do not match the hash its build recorded, or its folder is not safe:
        it is not loaded.
    """

    def __init__(self, build: GeneratedCode) -> None:
        if (
            not isinstance(build, GeneratedCode)
            or build.library is None
            or "cost_batch" not in build.functions
        ):
            raise ValueError(
                "build must be a compiled GeneratedCode with 'cost_batch' (generate_c(..., "
                f"functions=(..., 'cost_batch'))), got {check.shown(build)}"
            )
        self.build = build
        batch = build.functions["cost_batch"]
        self.dim, self.population = (int(n) for n in batch.size_in(0))
        self.parameter_dim = int(batch.numel_in(1))
        self.library = ctypes.CDLL(str(verify_library(build.library)))
        pointer = ctypes.POINTER(ctypes.c_double)
        tail: list[Any] = [ctypes.c_double, ctypes.c_double, *[ctypes.c_int] * 3, *[pointer] * 4]
        prefix = build.prefix
        self._given = getattr(self.library, f"{prefix}uuv_ocp_igwo")
        self._given.argtypes = [pointer] * 8 + tail
        self._drawing = getattr(self.library, f"{prefix}uuv_ocp_igwo_pcg64")
        words: list[Any] = [ctypes.POINTER(ctypes.c_uint64), ctypes.c_int]
        self._drawing.argtypes = [*[pointer] * 5, *words, *[pointer] * 2, *tail]
        for function in (self._given, self._drawing):
            function.restype = ctypes.c_int
        self.random = getattr(self.library, f"{prefix}uuv_ocp_pcg64_random")
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
        but never waits for it, as the step does for a block its worker is late with, ``3``
        draws the odd blocks on the step's thread and waits for the worker's even ones (test
        modes; the numbers are the same in every case).  ``late_blocks`` in the result counts the
        iterations whose numbers the step drew itself because the second thread was late.

        Shapes (``dim`` and ``population`` are the build's): ``p (parameter_dim,)``,
        ``offset``, ``lower``, ``upper (dim,)``, ``positions (population, dim)``, ``a`` and
        ``w (iterations,)``, ``draws (iterations, 8, population, dim)``.  Anything else raises
        ``ValueError`` naming the argument (the C step would read past the arrays).
        """
        population, dim, iterations = self.population, self.dim, self._iterations(a)
        pointer = ctypes.POINTER(ctypes.c_double)

        def data(array: np.ndarray) -> ctypes._Pointer:
            return array.ctypes.data_as(pointer)

        shapes = {
            "p": (self.parameter_dim,),
            "offset": (dim,),
            "lower": (dim,),
            "upper": (dim,),
            "positions": (population, dim),
        }
        given = {"p": p, "offset": offset, "lower": lower, "upper": upper, "positions": positions}
        inputs = [_float_array(name, given[name], shape) for name, shape in shapes.items()]
        schedules = [_float_array(name, v, (iterations,)) for name, v in (("a", a), ("w", w))]
        c1, c2 = check.finite_float("c1", c1), check.finite_float("c2", c2)
        if isinstance(rng_thread, bool):
            rng_thread = int(rng_thread)
        elif not isinstance(rng_thread, numbers.Integral) or rng_thread not in (0, 1, 2, 3):
            raise ValueError(f"rng_thread must be True, False, 2 or 3, got {check.shown(rng_thread)}")
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
            block = _float_array("draws", draws, (iterations, 8, population, dim))
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

    @staticmethod
    def _iterations(a: object) -> int:
        shape = np.shape(a) if isinstance(a, np.ndarray | list | tuple) else None
        if shape is None or len(shape) != 1:
            raise ValueError(f"a must be a 1-D array (one value per iteration), got {check.shown(a)}")
        return int(shape[0])


def _float_array(name: str, value: object, shape: tuple[int, ...]) -> np.ndarray:
    """``value`` as a C-contiguous float64 array of exactly ``shape`` (else ``ValueError``)."""
    try:
        array = np.ascontiguousarray(value, dtype=float)
    except (TypeError, ValueError) as error:
        raise ValueError(f"{name} must be a real array of shape {shape}, got {check.shown(value)}") from error
    if array.shape != shape:
        raise ValueError(f"{name} must have shape {shape} (the build's sizes), got shape {array.shape}")
    return array


def uses_pcg64(generator: np.random.Generator) -> bool:
    """Whether ``generator`` runs on numpy's PCG64, the stream the C step reproduces."""
    return type(generator.bit_generator) is np.random.PCG64


def _split(value: int) -> tuple[int, int]:
    return value >> 64, value & 0xFFFFFFFFFFFFFFFF
