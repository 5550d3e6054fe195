"""Nothing is loaded that this package did not build, nor from a folder others can write.

Loading a shared library runs its constructors, so a check after loading is too late.  Every
load that could meet a planted or damaged file runs in a subprocess: glibc's ``dlopen`` hands
back an already loaded library by path (the test process must not have loaded the file before
it is tampered with), and a truncated library kills its process with SIGBUS, which must not
take the test run down with it when the protection regresses.
"""

import json
import os
import stat
import subprocess
import sys
import textwrap
import warnings
from pathlib import Path

import casadi as ca
import numpy as np
import pytest

import uuv_ocp as uo
from tests.conftest import needs_compiler
from uuv_ocp import _version as uuv_version
from uuv_ocp import codegen
from uuv_ocp.judge import instance_parameters
from uuv_ocp.native import compile as cg
from uuv_ocp.native.compile import (
    HASH_SUFFIX,
    BuildDirectoryError,
    IntegrityError,
    compile_functions,
    library_intact,
    secure_directory,
    verify_library,
)
from uuv_ocp.solvers import new_solver
from uuv_ocp.solvers.result import Stage

FUNCTION = "x = ca.SX.sym('x', 5)\nf = ca.Function('sec', [x], [ca.sumsqr(ca.sin(x) * x)])\n"
BUILD = (
    "import casadi as ca, json, os, sys\n"
    "from uuv_ocp.native.compile import compile_functions\n"
    f"{FUNCTION}"
    "lib = compile_functions([f], sys.argv[1], name='sec_gen')\n"
    "value = float(lib['sec'](list(range(5))))\n"
    "print(json.dumps({'path': str(lib.path), 'reused': lib.reused, 'value': value}))\n"
)
PLANTED_C = textwrap.dedent(
    """
    #include <stdio.h>
    __attribute__((constructor)) static void planted(void) {
      FILE* f = fopen("%s", "w");
      if (f) { fputs("planted constructor ran\\n", f); fclose(f); }
    }
    int sec(void) { return 0; }
    """
)


def _build_in_subprocess(directory: Path, umask: int | None = None) -> dict:
    """Build (or reuse) FUNCTION's library in ``directory`` in a child process (with ``umask``)."""
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)}
    script = BUILD if umask is None else f"import os\nos.umask({umask:#o})\n{BUILD}"
    completed = subprocess.run(
        [sys.executable, "-c", script, str(directory)],
        capture_output=True,
        text=True,
        timeout=120,
        env=env,
    )
    # a negative status is a signal: -7 is the SIGBUS of a library mapped past its end
    assert completed.returncode == 0, f"exit {completed.returncode}\n{completed.stderr}"
    return json.loads(completed.stdout.strip().splitlines()[-1])


def _planted_library(tmp_path: Path, marker: Path) -> Path:
    source = tmp_path / "planted.c"
    source.write_text(PLANTED_C % marker)
    library = tmp_path / "planted.so"
    compiler = cg.find_c_compiler()
    subprocess.run([compiler, "-shared", "-fPIC", str(source), "-o", str(library)], check=True)
    return library


def _expected_value() -> float:
    x = np.arange(5.0)
    return float(np.sum((np.sin(x) * x) ** 2))


@pytest.fixture
def compiler():
    try:
        return cg.find_c_compiler()
    except cg.CompilerNotFoundError as error:
        pytest.skip(str(error))


# -- planted, modified and truncated libraries ------------------------------------------------


def test_build_records_the_hash_of_the_library(compiler, tmp_path):
    first = _build_in_subprocess(tmp_path / "cache")
    library = Path(first["path"])
    sidecar = library.with_name(library.name + HASH_SUFFIX)
    assert not first["reused"] and library.is_absolute()
    assert sidecar.read_text().strip() == cg._file_sha256(library)
    assert library_intact(library)
    assert stat.S_IMODE((tmp_path / "cache").stat().st_mode) == 0o700
    again = _build_in_subprocess(tmp_path / "cache")
    assert again["reused"] and again["value"] == pytest.approx(_expected_value(), rel=1e-12)


@pytest.mark.parametrize("sidecar", ["missing", "kept"])
def test_planted_library_is_rebuilt_and_its_constructor_never_runs(compiler, tmp_path, sidecar):
    """A library at the cache's predicted name (without or with a stale hash) is never loaded."""
    directory = tmp_path / "cache"
    library = Path(_build_in_subprocess(directory)["path"])
    marker = tmp_path / "marker"
    planted = _planted_library(tmp_path, marker)
    os.replace(planted, library)
    if sidecar == "missing":
        library.with_name(library.name + HASH_SUFFIX).unlink()
    assert not library_intact(library)

    rebuilt = _build_in_subprocess(directory)
    assert not marker.exists(), "the planted library's constructor ran"
    assert not rebuilt["reused"] and rebuilt["path"] == str(library)
    assert rebuilt["value"] == pytest.approx(_expected_value(), rel=1e-12)
    assert library_intact(library)


def test_truncated_library_is_detected_and_rebuilt(compiler, tmp_path):
    """A library cut short (full disk, killed copy) used to kill every later run with SIGBUS."""
    directory = tmp_path / "cache"
    library = Path(_build_in_subprocess(directory)["path"])
    size = library.stat().st_size
    with library.open("r+b") as handle:
        handle.truncate(size // 2)
    assert not library_intact(library)
    rebuilt = _build_in_subprocess(directory)
    assert not rebuilt["reused"]
    assert rebuilt["value"] == pytest.approx(_expected_value(), rel=1e-12)
    assert library.stat().st_size == size and library_intact(library)


def _rewrite_sidecar(library: Path) -> None:
    """Record the library's present bytes in its sidecar, as whoever changed it could."""
    library.with_name(library.name + HASH_SUFFIX).write_text(cg._file_sha256(library) + "\n")


def test_truncated_library_with_a_matching_sidecar_is_rebuilt_not_mapped(compiler, tmp_path):
    """A library cut short whose sidecar matches its bytes killed the next run with SIGBUS.

    The hash cannot tell (the sidecar was written for the cut file, e.g. by a copy that stopped
    at a full disk and hashed what it had); the ELF headers, which still describe the whole
    library, can: its segments end past the end of the file.
    """
    directory = tmp_path / "cache"
    library = Path(_build_in_subprocess(directory)["path"])
    size = library.stat().st_size

    def cut() -> None:
        with library.open("r+b") as handle:
            handle.truncate(size // 2)
        _rewrite_sidecar(library)

    cut()
    rebuilt = _build_in_subprocess(directory)  # used to die with SIGBUS (exit -7)
    assert not rebuilt["reused"]
    assert rebuilt["value"] == pytest.approx(_expected_value(), rel=1e-12)
    assert library.stat().st_size == size and library_intact(library)
    cut()
    assert not library_intact(library)
    with pytest.raises(IntegrityError, match="truncated"):
        verify_library(library)


def test_elf_check_finds_every_cut_of_a_library(compiler, tmp_path):
    """Any prefix of a library (down to its first bytes) is refused, the whole file accepted."""
    library = Path(_build_in_subprocess(tmp_path / "cache")["path"])
    data = library.read_bytes()
    assert cg._elf_problem(data) is None
    for cut in (3, 16, 40, 64, 100, 1000, len(data) // 3, len(data) // 2, len(data) - 1):
        assert cg._elf_problem(data[:cut]) is not None, f"a library cut at {cut} bytes was accepted"
    assert "not an ELF file" in cg._elf_problem(b"#!/bin/sh\necho planted\n" * 100)
    relocatable = bytearray(data)
    relocatable[16] = 1  # ET_REL: an object file, not a shared library
    assert "not a shared library" in cg._elf_problem(bytes(relocatable))


def test_umask_002_gives_private_files_and_a_group_member_cannot_plant(compiler, tmp_path):
    """With umask 002 a group member could rewrite a library and its sidecar: now refused.

    The issue's scenario: libraries came out 0775 and sidecars 0664 in a 0755 folder that
    passed the folder check; a group member rewrote both and the next run loaded the plant.
    """
    directory = tmp_path / "cache"
    library = Path(_build_in_subprocess(directory, umask=0o002)["path"])
    assert stat.S_IMODE(directory.stat().st_mode) == 0o700
    written = sorted(directory.iterdir())
    assert {path.suffix for path in written} == {".c", ".h", ".so", HASH_SUFFIX}
    for path in written:
        assert stat.S_IMODE(path.stat().st_mode) == 0o600, f"{path.name} is not private"

    # what a group member could do with a 0755 folder and group-writable files: rewrite both
    directory.chmod(0o755)  # not group-writable: the folder check passes
    marker = tmp_path / "marker"
    library.write_bytes(_planted_library(tmp_path, marker).read_bytes())
    _rewrite_sidecar(library)
    library.chmod(0o775)
    library.with_name(library.name + HASH_SUFFIX).chmod(0o664)
    with pytest.raises(IntegrityError, match="writable by its group or by others"):
        verify_library(library)
    rebuilt = _build_in_subprocess(directory, umask=0o002)
    assert not marker.exists(), "the planted library's constructor ran"
    assert not rebuilt["reused"] and rebuilt["value"] == pytest.approx(_expected_value(), rel=1e-12)
    assert stat.S_IMODE(library.stat().st_mode) == 0o600 and library_intact(library)


@pytest.mark.parametrize("linked", ["library", "sidecar"])
def test_symlinked_library_files_are_refused_and_replaced(compiler, tmp_path, linked):
    """A link to an intact library elsewhere (its sidecar copied) is not loaded through the link."""
    elsewhere = Path(_build_in_subprocess(tmp_path / "elsewhere")["path"])
    directory = secure_directory(tmp_path / "cache")
    library = directory / elsewhere.name
    sidecar = library.with_name(library.name + HASH_SUFFIX)
    original_sidecar = elsewhere.with_name(elsewhere.name + HASH_SUFFIX)
    if linked == "library":
        library.symlink_to(elsewhere)
        sidecar.write_bytes(original_sidecar.read_bytes())
        sidecar.chmod(0o600)
    else:
        library.write_bytes(elsewhere.read_bytes())
        library.chmod(0o600)
        sidecar.symlink_to(original_sidecar)
    assert not library_intact(library)
    with pytest.raises(IntegrityError, match="symbolic link"):
        verify_library(library)
    rebuilt = _build_in_subprocess(directory)
    assert not rebuilt["reused"] and rebuilt["path"] == str(library)
    assert not library.is_symlink() and not sidecar.is_symlink() and library_intact(library)
    assert library_intact(elsewhere)  # replaced the link, not what it pointed to


def test_fifo_at_the_library_path_is_refused_without_hanging(tmp_path):
    """Reading a FIFO blocks until someone writes: the check opens without blocking."""
    directory = secure_directory(tmp_path / "cache")
    library = directory / "sec_gen_0123456789abcdef.so"
    os.mkfifo(library, 0o600)
    library.with_name(library.name + HASH_SUFFIX).write_text("0" * 64 + "\n")
    script = (
        "import sys\nfrom uuv_ocp.native.compile import library_intact\nprint(library_intact(sys.argv[1]))\n"
    )
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)}
    completed = subprocess.run(
        [sys.executable, "-c", script, str(library)], capture_output=True, text=True, timeout=60, env=env
    )
    assert completed.stdout.strip() == "False", completed.stderr


def test_private_file_checks_name_the_reason(tmp_path):
    path = tmp_path / "file"
    path.write_bytes(b"data")
    path.chmod(0o600)
    assert cg.read_private_file(path) == b"data" and cg.check_private_file(path) == path
    path.chmod(0o620)
    with pytest.raises(IntegrityError, match=r"writable by its group or by others \(mode 0620\)"):
        cg.read_private_file(path)
    link = tmp_path / "link"
    link.symlink_to(path)
    with pytest.raises(IntegrityError, match="symbolic link"):
        cg.check_private_file(link)
    with pytest.raises(IntegrityError, match="not a regular file"):
        cg.check_private_file(tmp_path)


@pytest.mark.skipif(not hasattr(os, "geteuid") or os.geteuid() != 0, reason="chown needs root")
def test_library_owned_by_another_user_is_refused(compiler, tmp_path):
    library = Path(_build_in_subprocess(tmp_path / "cache")["path"])
    os.chown(library, 65534, -1)
    with pytest.raises(IntegrityError, match="owned by uid 65534"):
        verify_library(library)


def test_written_files_are_private_whatever_the_umask(tmp_path):
    """Sources and headers (compile=False) and sidecars are written 0600 under umask 0."""
    exec(FUNCTION, globals())
    previous = os.umask(0)
    try:
        generated = compile_functions([f], tmp_path / "out", compile=False)  # noqa: F821
        cg._write_private(tmp_path / "out" / "note", b"x")
    finally:
        os.umask(previous)
    for path in (generated.source, generated.header, tmp_path / "out" / "note"):
        assert stat.S_IMODE(path.stat().st_mode) == 0o600, path.name
    assert stat.S_IMODE((tmp_path / "out").stat().st_mode) == 0o700


def test_missing_parents_of_a_cache_are_created_private(tmp_path):
    previous = os.umask(0o002)
    try:
        created = secure_directory(tmp_path / "a" / "b" / "c")
    finally:
        os.umask(previous)
    for folder in (tmp_path / "a", tmp_path / "a" / "b", created):
        assert stat.S_IMODE(folder.stat().st_mode) == 0o700, folder


# -- the cache key: one cache shared by several installations ------------------------------------


def test_cache_key_covers_package_casadi_and_compiler_versions(compiler, tmp_path, monkeypatch):
    """Two checkouts or venvs sharing a cache never reuse each other's library across versions."""
    wrapper = tmp_path / "cc-wrapper"

    def write_wrapper(version: str) -> None:
        wrapper.write_text(
            f'#!/bin/sh\nif [ "$1" = --version ]; then echo "wrapped cc {version}"; exit 0; fi\n'
            f'exec {compiler} "$@"\n'
        )
        wrapper.chmod(0o700)

    write_wrapper("1.0")
    exec(FUNCTION, globals())

    def digest() -> str:
        library = compile_functions([f], tmp_path / "cache", name="key_gen", cc=str(wrapper))  # noqa: F821
        assert library.path is not None and library.path.name == f"key_gen_{library.digest[:16]}.so"
        return library.digest

    base = digest()
    assert digest() == base  # reproducible
    monkeypatch.setattr(uuv_version, "__version__", "0.0.0-other-checkout")  # the one source of it
    other_package = digest()
    monkeypatch.undo()
    monkeypatch.setattr(ca, "__version__", "0.0.0-other-casadi")
    other_casadi = digest()
    monkeypatch.undo()
    os.utime(wrapper, ns=(0, 10**18))  # the compiler upgraded in place: a new mtime ...
    write_wrapper("2.0")  # ... and a new version line
    other_compiler = digest()
    assert len({base, other_package, other_casadi, other_compiler}) == 4


def test_the_test_suite_uses_a_cache_of_its_own():
    """The suite's results must not depend on what another checkout built in ~/.cache/uuv_ocp."""
    cache = codegen.default_cache_directory()
    checkout = Path(__file__).resolve().parents[2]
    configured = os.environ.get("UUV_OCP_TEST_CACHE", "").strip()
    expected = Path(os.path.abspath(configured)) if configured else checkout / "build" / "test-cache"
    assert cache == expected
    assert os.environ.get("UUV_OCP_HPIPM") in ("wheel", "auto", "native")


def test_native_igwo_refuses_a_library_that_was_not_built_here(compiler, tmp_path):
    marker = tmp_path / "marker"
    folder = secure_directory(tmp_path / "lib")
    planted = folder / "uuv_ocp_gen_0123456789abcdef.so"
    os.replace(_planted_library(tmp_path, marker), planted)
    x, p = ca.SX.sym("x", 6, 4), ca.SX.sym("p", 3)
    fake = codegen.GeneratedCode(
        directory=folder,
        source=folder / "x.c",
        header=folder / "x.h",
        library=planted,
        functions={"cost_batch": ca.Function("cost_batch", [x, p], [ca.sum1(x)])},
        population=4,
    )
    with pytest.raises(IntegrityError, match="refusing to load"):
        codegen.NativeIgwo(fake)
    # a sidecar with another hash does not make it loadable either
    planted.with_name(planted.name + HASH_SUFFIX).write_text("0" * 64 + "\n")
    with pytest.raises(IntegrityError, match=str(planted)):
        codegen.NativeIgwo(fake)
    assert not marker.exists()


PLANTED_SOLVE = (
    "import os, sys, warnings, numpy as np, uuv_ocp as uo\n"
    "problem = uo.TrackingProblem(uo.Vehicle.rexrov(), uo.Reference.paper('s2'), horizon=4)\n"
    "x0 = uo.Reference.paper('s2').evaluate([0.0])[0]\n"
    "with warnings.catch_warnings():\n"
    "    warnings.simplefilter('error')\n"
    "    result = uo.solve(problem, 'igwo', x0=x0, options={'compiled': True, 'population': 4,"
    " 'iterations': 3, 'seed': 1})\n"
    "print(np.isfinite(result.cost))\n"
)


@needs_compiler
def test_planted_library_in_the_solver_cache_is_not_run_by_a_compiled_swarm(tmp_path):
    """The issue's scenario: solve(problem, 'igwo', compiled=True) with a planted cache entry."""
    cache = tmp_path / "cache"
    env = {**os.environ, "UUV_OCP_CACHE": str(cache), "UUV_OCP_COMPILED": "1"}
    env["PYTHONPATH"] = os.pathsep.join(sys.path)

    def run() -> str:
        completed = subprocess.run(
            [sys.executable, "-c", PLANTED_SOLVE], capture_output=True, text=True, timeout=300, env=env
        )
        assert completed.returncode == 0, f"exit {completed.returncode}\n{completed.stderr[-3000:]}"
        return completed.stdout.strip()

    assert run() == "True"
    (library,) = cache.glob("uuv_ocp_gen_*.so")
    marker = tmp_path / "marker"
    os.replace(_planted_library(tmp_path, marker), library)
    assert run() == "True"
    assert not marker.exists(), "the planted library's constructor ran inside solve()"
    assert library_intact(library)


# -- relative paths are loaded absolutely ------------------------------------------------------


def test_relative_cache_path_is_loaded_by_absolute_path(compiler, tmp_path, monkeypatch):
    work = tmp_path / "work"
    work.mkdir(mode=0o700)
    monkeypatch.chdir(work)
    monkeypatch.setenv("UUV_OCP_CACHE", ".")
    assert codegen.default_cache_directory() == work
    loaded_from: list[str] = []
    external = cg.ca.external

    def spy(name, path):
        loaded_from.append(path)
        return external(name, path)

    monkeypatch.setattr(cg.ca, "external", spy)
    exec(FUNCTION, globals())  # defines f
    library = compile_functions([f], ".", name="rel_gen")  # noqa: F821
    assert library.path is not None and library.path.is_absolute()
    assert library.path.parent == work
    assert loaded_from and all(os.path.isabs(path) for path in loaded_from)
    assert verify_library(Path(library.path.name)) == library.path  # bare name -> absolute


def test_empty_cache_variable_means_the_default(monkeypatch):
    monkeypatch.setenv("UUV_OCP_CACHE", "")
    assert codegen.default_cache_directory() == Path.home() / ".cache" / "uuv_ocp"
    monkeypatch.setenv("UUV_OCP_CACHE", "relative/cache")
    assert codegen.default_cache_directory() == Path.cwd() / "relative" / "cache"


# -- unsafe folders ----------------------------------------------------------------------------


@pytest.mark.parametrize("mode", [0o777, 0o770, 0o702])
def test_group_or_world_writable_folder_is_refused(tmp_path, mode):
    folder = tmp_path / "shared"
    folder.mkdir()
    folder.chmod(mode)
    exec(FUNCTION, globals())
    with pytest.raises(BuildDirectoryError, match="writable by its group or by others") as info:
        compile_functions([f], folder, compile=False)  # noqa: F821
    assert str(folder) in str(info.value) and "chmod go-w" in str(info.value)
    assert list(folder.iterdir()) == [], "something was written to the refused folder"


def test_generate_c_refuses_a_world_writable_directory(tmp_path):
    folder = tmp_path / "out"
    folder.mkdir()
    folder.chmod(0o777)
    problem = uo.TrackingProblem(uo.Vehicle.rexrov(), uo.Reference.paper("s2"), horizon=3)
    with pytest.raises(BuildDirectoryError, match=str(folder)):
        uo.generate_c(problem, folder, compile=False)


@pytest.mark.skipif(not hasattr(os, "geteuid") or os.geteuid() != 0, reason="chown needs root")
def test_folder_owned_by_another_user_is_refused(tmp_path):
    folder = tmp_path / "theirs"
    folder.mkdir(mode=0o700)
    os.chown(folder, 65534, -1)
    with pytest.raises(BuildDirectoryError, match="owned by uid 65534"):
        secure_directory(folder)


def test_new_folders_are_private_and_files_are_not_folders(tmp_path):
    created = secure_directory(tmp_path / "a" / "b")
    assert created.is_absolute() and stat.S_IMODE(created.stat().st_mode) == 0o700
    (tmp_path / "file").write_text("")
    with pytest.raises(BuildDirectoryError, match="not a directory"):
        secure_directory(tmp_path / "file")
    with pytest.raises(BuildDirectoryError, match="not usable"):
        secure_directory(tmp_path / "missing", create=False)


def test_unsafe_solver_cache_warns_and_falls_back(tmp_path, monkeypatch):
    """Like a missing compiler: one warning naming the folder, then the virtual machine."""
    cache = tmp_path / "cache"
    cache.mkdir()
    cache.chmod(0o777)
    monkeypatch.setenv("UUV_OCP_CACHE", str(cache))
    problem = uo.TrackingProblem(uo.Vehicle.rexrov(), uo.Reference.paper("s2"), horizon=3)
    with pytest.warns(RuntimeWarning, match=str(cache)):
        build = codegen.compiled_build(problem, 4)
    assert build is None and list(cache.iterdir()) == []


def test_unwritable_solver_cache_warns_and_falls_back(tmp_path, monkeypatch):
    """A cache the user cannot write (simulated: root may write anywhere) no longer raises."""
    cache = secure_directory(tmp_path / "cache")
    monkeypatch.setenv("UUV_OCP_CACHE", str(cache))
    real_access = os.access
    monkeypatch.setattr(
        cg.os, "access", lambda path, mode: False if Path(path) == cache else real_access(path, mode)
    )
    problem = uo.TrackingProblem(uo.Vehicle.rexrov(), uo.Reference.paper("s2"), horizon=3)
    with pytest.warns(RuntimeWarning, match=rf"{cache} is not writable"):
        assert codegen.compiled_build(problem, 4) is None


def test_cache_that_cannot_be_created_warns_and_falls_back(tmp_path, monkeypatch):
    blocker = tmp_path / "file"
    blocker.write_text("")
    monkeypatch.setenv("UUV_OCP_CACHE", str(blocker / "cache"))
    problem = uo.TrackingProblem(uo.Vehicle.rexrov(), uo.Reference.paper("s2"), horizon=3)
    with pytest.warns(RuntimeWarning, match="cannot create the build folder"):
        assert codegen.compiled_build(problem, 4) is None


# -- CasADi's JIT of the exact solvers ---------------------------------------------------------


@needs_compiler
def test_compiled_exact_solve_leaves_no_jit_files_in_the_working_directory(tmp_path, monkeypatch):
    work = tmp_path / "work"
    work.mkdir()
    monkeypatch.chdir(work)
    monkeypatch.setenv("UUV_OCP_CACHE", str(tmp_path / "cache"))
    problem = uo.TrackingProblem(uo.Vehicle.rexrov(), uo.Reference.paper("s2"), horizon=4, terminal="none")
    x0 = uo.Reference.paper("s2").evaluate([0.0])[0]
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a fallback to the virtual machine would warn
        solver = uo.get_solver(problem, "ipopt", {"compiled": True})
        result = uo.solve(problem, "ipopt", x0=x0, options={"compiled": True})
    assert solver.compiled and result.success
    assert list(work.iterdir()) == [], "the compiled NLP's build wrote into the working directory"
    assert Path.cwd() == work
    cache = tmp_path / "cache"
    assert stat.S_IMODE(cache.stat().st_mode) == 0o700
    assert list(cache.glob("uuv_ocp_nlp_ipopt_*.so")), "the NLP library is kept in the solvers' cache"


def _counted_compiles(monkeypatch) -> list:
    """Spy on the compiler runs of :mod:`uuv_ocp.native.compile` (one entry per compile)."""
    calls: list = []
    real = cg._compile

    def spy(command, temporary, final):
        calls.append(final)
        return real(command, temporary, final)

    monkeypatch.setattr(cg, "_compile", spy)
    return calls


def _compiled_fatrop(monkeypatch, tmp_path):
    """Return a small problem, its instance parameters and the compiles counted (-O0: flags untested)."""
    from uuv_ocp.native import runtime

    monkeypatch.setenv("UUV_OCP_CACHE", str(tmp_path / "cache"))
    monkeypatch.setattr(runtime, "NLP_FLAGS", ("-O0", "-fPIC", "-shared"))  # the quickest compile
    problem = uo.TrackingProblem(uo.Vehicle.rexrov(), uo.Reference.paper("s2"), horizon=3, terminal="none")
    x0 = uo.Reference.paper("s2").evaluate([0.0])[0]
    return problem, instance_parameters(problem, x0, 0.0), _counted_compiles(monkeypatch)


def _fresh_fatrop(problem, p, compiled=True):
    """Solve ``p`` with a new fatrop backend (nothing shared with an earlier one but the disk cache)."""
    return new_solver(problem, "fatrop", {"compiled": compiled}).solve(p, None)


@needs_compiler
def test_compiled_nlp_is_built_once_and_reused_from_the_cache(tmp_path, monkeypatch):
    problem, p, compiles = _compiled_fatrop(monkeypatch, tmp_path)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a fallback to the virtual machine would warn
        first = _fresh_fatrop(problem, p)
        built = len(compiles)
        second = _fresh_fatrop(problem, p)
    virtual = _fresh_fatrop(problem, p, compiled=False)
    assert built >= 1 and len(compiles) == built, "the second solver compiled again"
    assert first.success and second.success
    np.testing.assert_allclose(second.controls, first.controls, rtol=0, atol=1e-12)
    # the compiled functions are verified to 1e-12 against the virtual machine's: same iterates
    np.testing.assert_allclose(first.controls, virtual.controls, rtol=1e-9, atol=1e-9)


@needs_compiler
def test_robust_retry_of_the_same_plugin_reuses_the_plain_attempts_library(tmp_path, monkeypatch):
    problem, p, compiles = _compiled_fatrop(monkeypatch, tmp_path)
    solver = new_solver(problem, "fatrop", {"compiled": True})
    assert solver.robust_options() and "plugin" not in solver.robust_options(), "a same-plugin retry"
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a fallback to the virtual machine would warn
        variant = next(iter(solver.variants))
        plain = solver._solver(variant, Stage.PLAIN, False)
        built = len(compiles)
        robust = solver._solver(variant, Stage.ROBUST, False)
    assert built >= 1 and len(compiles) == built, "the robust retry compiled the plain attempt's again"
    assert plain is not robust, "two solvers (their options differ), one library"
    libraries = sorted((tmp_path / "cache").glob("uuv_ocp_nlp_fatrop_*.so"))
    assert len(libraries) == built


@needs_compiler
def test_tampered_compiled_nlp_library_is_rejected_and_rebuilt(tmp_path, monkeypatch):
    problem, p, compiles = _compiled_fatrop(monkeypatch, tmp_path)
    first = _fresh_fatrop(problem, p)
    libraries = sorted((tmp_path / "cache").glob("uuv_ocp_nlp_fatrop_*.so"))
    assert libraries and len(compiles) == len(libraries)
    for library in libraries:  # one byte changed in each: its sidecar's SHA-256 no longer matches
        data = bytearray(library.read_bytes())
        data[len(data) // 2] ^= 0xFF
        library.write_bytes(bytes(data))
        assert not cg.library_intact(library)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        again = _fresh_fatrop(problem, p)
    assert len(compiles) == 2 * len(libraries), "a tampered library was loaded instead of rebuilt"
    assert all(cg.library_intact(library) for library in libraries)
    np.testing.assert_allclose(again.controls, first.controls, rtol=0, atol=1e-12)


def test_jit_workspace_restores_the_working_directory_on_error(tmp_path, monkeypatch):
    work = tmp_path / "work"
    work.mkdir()
    monkeypatch.chdir(work)
    with pytest.raises(RuntimeError, match="inside"), cg.jit_workspace(tmp_path / "jit") as folder:
        assert Path.cwd() == tmp_path / "jit" and folder.endswith(os.sep)
        raise RuntimeError("inside")
    assert Path.cwd() == work


# -- NativeIgwo.run checks every length ----------------------------------------------------------


@pytest.fixture(scope="module")
def native(tmp_path_factory):
    try:
        cg.find_c_compiler()
    except cg.CompilerNotFoundError as error:
        pytest.skip(str(error))
    problem = uo.TrackingProblem(uo.Vehicle.rexrov(), uo.Reference.paper("s2"), horizon=4)
    build = codegen.generate_c(
        problem,
        tmp_path_factory.mktemp("native"),
        functions=("cost_batch",),
        population=4,
    )
    x0 = uo.Reference.paper("s2").evaluate([0.0])[0]
    return codegen.NativeIgwo(build), problem.parameters(x0, 0.0), problem.control_dim


def _arguments(native, iterations=3):
    step, p, dim = native
    rng = np.random.default_rng(0)
    return {
        "p": p,
        "offset": np.zeros(dim),
        "lower": -np.ones(dim),
        "upper": np.ones(dim),
        "positions": rng.uniform(-1, 1, (4, dim)),
        "draws": rng.random((iterations, 8, 4, dim)),
        "a": np.linspace(2, 0, iterations),
        "w": np.full(iterations, 0.5),
    }


def test_native_igwo_runs_with_the_right_shapes(native):
    step = native[0]
    out = step.run(**_arguments(native))
    assert np.isfinite(out["fun"]) and out["history"].shape == (4,)


@pytest.mark.parametrize(
    ("name", "change"),
    [
        ("p", lambda v: v[:-1]),
        ("offset", lambda v: v[:3]),
        ("lower", lambda v: np.zeros(0)),
        ("upper", lambda v: np.append(v, 1.0)),
        ("positions", lambda v: v[:2]),
        ("positions", lambda v: v[:, :5]),
        ("positions", lambda v: v.ravel()),
        ("draws", lambda v: v[:, :7]),
        ("draws", lambda v: v[:2]),
        ("w", lambda v: v[:1]),
        ("a", lambda v: v.reshape(1, -1)),
        ("p", lambda v: "abc"),
    ],
)
def test_native_igwo_rejects_short_or_misshapen_inputs(native, name, change):
    arguments = _arguments(native)
    arguments[name] = change(arguments[name])
    with pytest.raises(ValueError, match=rf"^{name} must"):
        native[0].run(**arguments)


def test_native_igwo_rejects_bad_scalars(native):
    with pytest.raises(ValueError, match="c1 must be finite"):
        native[0].run(**_arguments(native), c1=float("nan"))
    with pytest.raises(ValueError, match="rng_thread"):
        native[0].run(**_arguments(native), rng_thread=7)
    with pytest.raises(ValueError, match="build must be a compiled GeneratedCode"):
        codegen.NativeIgwo(None)  # type: ignore[arg-type]
