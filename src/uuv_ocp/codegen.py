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

This module is the users' facade (``from uuv_ocp import codegen``, ``uuv_ocp.codegen.generate_c``):
it holds no code and nothing inside the package imports it.  The native runtime (generation of
the cost functions, :func:`compiled_build`, :class:`NativeIgwo`, :func:`jit_directory`, the HPIPM
flags) lives in :mod:`uuv_ocp.native.runtime`, compilation and the cache in
:mod:`uuv_ocp.native.compile`, and the NMPC step with the full :func:`generate_c` in
:mod:`uuv_ocp.solvers.rti_export` (it needs the RTI solver): layers import only downwards.
"""

from uuv_ocp.native.compile import (
    BuildDirectoryError,
    CodegenError,
    CompilationError,
    CompilerNotFoundError,
    IntegrityError,
    VerificationError,
    compile_functions,
    default_cache_directory,
    find_c_compiler,
    jit_workspace,
    verify_library,
)
from uuv_ocp.native.runtime import (
    ACCEPTED_NAMES,
    CORE_FLAGS,
    DEFAULT_FLAGS,
    EXACT_BATCH,
    FUNCTION_NAMES,
    IGWO_HEADER,
    MIN_IGWO_POPULATION,
    NMPC_STEP,
    SIMD_TOLERANCE,
    GeneratedCode,
    NativeIgwo,
    compiled_build,
    hpipm_link_flags,
    jit_directory,
    symbolic_functions,
    uses_pcg64,
)
from uuv_ocp.solvers.rti_export import (
    NMPC_CHECK_STATES,
    NMPC_CONIC_TOLERANCE,
    NMPC_TOLERANCE,
    check_nmpc_step,
    generate_c,
    nmpc_library,
)

__all__ = [
    "ACCEPTED_NAMES",
    "CORE_FLAGS",
    "DEFAULT_FLAGS",
    "EXACT_BATCH",
    "FUNCTION_NAMES",
    "IGWO_HEADER",
    "MIN_IGWO_POPULATION",
    "NMPC_CHECK_STATES",
    "NMPC_CONIC_TOLERANCE",
    "NMPC_STEP",
    "NMPC_TOLERANCE",
    "SIMD_TOLERANCE",
    "BuildDirectoryError",
    "CodegenError",
    "CompilationError",
    "CompilerNotFoundError",
    "GeneratedCode",
    "IntegrityError",
    "NativeIgwo",
    "VerificationError",
    "check_nmpc_step",
    "compile_functions",
    "compiled_build",
    "default_cache_directory",
    "find_c_compiler",
    "generate_c",
    "hpipm_link_flags",
    "jit_directory",
    "jit_workspace",
    "nmpc_library",
    "symbolic_functions",
    "uses_pcg64",
    "verify_library",
]
