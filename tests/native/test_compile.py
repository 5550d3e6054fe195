"""Generic code generation layer: compile, cache, load back, verify, fall back."""

import os
import stat
import subprocess
import sys
import warnings

import casadi as ca
import numpy as np
import pytest

from uuv_ocp.native import compile as cg
from uuv_ocp.native.compile import (
    CompilationError,
    CompilerNotFoundError,
    VerificationError,
    batched,
    compile_functions,
    find_c_compiler,
    load_or_fallback,
)

DIM = 6
POPULATION = 20


def _rosenbrock() -> ca.Function:
    """Rosenbrock cost with parameters (a, b): sum b (x_{i+1} - x_i^2)^2 + (a - x_i)^2."""
    x = ca.SX.sym("x", DIM)
    p = ca.SX.sym("p", 2)
    value = ca.sum1(p[1] * (x[1:] - x[:-1] ** 2) ** 2 + (p[0] - x[:-1]) ** 2)
    return ca.Function("rosen", [x, p], [value], ["x", "p"], ["f"])


def _pendulum_rk4() -> ca.Function:
    """One RK4 step of a damped, forced pendulum; the step length is an input."""
    x = ca.SX.sym("x", 2)
    u = ca.SX.sym("u")
    h = ca.SX.sym("h")

    def rhs(state):
        return ca.vertcat(state[1], -9.81 * ca.sin(state[0]) - 0.1 * state[1] + u)

    k1 = rhs(x)
    k2 = rhs(x + h / 2 * k1)
    k3 = rhs(x + h / 2 * k2)
    k4 = rhs(x + h * k3)
    x_next = x + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    return ca.Function("pendulum_rk4", [x, u, h], [x_next, ca.sumsqr(x_next)])


def _test_functions() -> list[ca.Function]:
    rosen = _rosenbrock()
    return [
        rosen,
        _pendulum_rk4(),
        batched(rosen, POPULATION),
        batched(rosen, 7, "thread", shared_inputs=[1]),
        batched(rosen, 9, "thread", shared_inputs=[1]),  # 2nd thread map of rosen: no clash
    ]


def _relative_error(a, b) -> float:
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    return float(np.max(np.abs(a - b) / np.maximum(1.0, np.abs(b))))


@pytest.fixture(scope="module")
def compiler():
    try:
        return find_c_compiler()
    except CompilerNotFoundError as error:
        pytest.skip(str(error))


@pytest.fixture(scope="module")
def build(compiler, tmp_path_factory):
    directory = tmp_path_factory.mktemp("codegen")
    return compile_functions(_test_functions(), directory, name="test_gen")


def _fake_compiler(directory, name="fake-cc", message="fake-cc: fatal error: out of cheese"):
    script = directory / name
    script.write_text(f'#!/bin/sh\necho "{message}" >&2\nexit 1\n')
    script.chmod(script.stat().st_mode | stat.S_IXUSR | stat.S_IXGRP | stat.S_IXOTH)
    return script


# -- compiled == symbolic --------------------------------------------------------------------


def test_files_and_names(build):
    assert build.source.name == "test_gen.c" and build.source.is_file()
    assert build.header.name == "test_gen.h" and build.header.is_file()
    assert build.path.name == f"test_gen_{build.digest[:16]}.so" and build.path.is_file()
    assert len(build.digest) == 64
    assert set(build.functions) == {
        "rosen",
        "pendulum_rk4",
        "rosen_batch20",
        "rosen_batch7",
        "rosen_batch9",
    }
    assert build["rosen"].name() == "rosen"
    with pytest.raises(KeyError, match="rosen_batch20"):
        build["missing"]
    assert all(error <= 1e-12 for error in build.max_error.values())
    assert not list(build.path.parent.glob(".*")), "temporary files left behind"


def test_compiled_matches_symbolic_independently(build):
    rng = np.random.default_rng(12345)
    for symbolic in _test_functions():
        compiled = build[symbolic.name()]
        assert compiled.n_in() == symbolic.n_in() and compiled.n_out() == symbolic.n_out()
        for _ in range(5):
            args = [rng.normal(size=symbolic.size_in(i)) for i in range(symbolic.n_in())]
            got, want = compiled.call(args), symbolic.call(args)
            for g, w in zip(got, want, strict=True):
                assert g.shape == w.shape
                assert _relative_error(g.full(), w.full()) <= 1e-12


def test_batched_maps_over_columns(build):
    rng = np.random.default_rng(7)
    rosen = _rosenbrock()
    population = rng.normal(size=(DIM, POPULATION))
    p = np.array([1.0, 100.0])
    columns = np.array([float(rosen(population[:, k], p)) for k in range(POPULATION)])
    # Non-shared p: CasADi repeats an (n, 1) argument horizontally.
    batch = np.asarray(build["rosen_batch20"](population, p)).ravel()
    assert batch.shape == (POPULATION,)
    assert _relative_error(batch, columns) <= 1e-12
    threaded = np.asarray(build["rosen_batch7"](population[:, :7], p)).ravel()
    assert _relative_error(threaded, columns[:7]) <= 1e-12


def test_batched_validation():
    rosen = _rosenbrock()
    mapped = batched(rosen, 5, shared_inputs=[1])
    assert mapped.name() == "rosen_batch5"
    assert mapped.size_in(0) == (DIM, 5) and mapped.size_in(1) == (2, 1)
    assert mapped.size_out(0) == (1, 5)
    assert batched(rosen, 1).size_in(0) == (DIM, 1)
    with pytest.raises(ValueError, match="population"):
        batched(rosen, 0)
    with pytest.raises(ValueError, match="parallelization"):
        batched(rosen, 3, "gpu")
    with pytest.raises(ValueError, match="shared_inputs"):
        batched(rosen, 3, shared_inputs=[2])
    m = ca.SX.sym("m", 2, 2)
    with pytest.raises(ValueError, match="column"):
        batched(ca.Function("mat", [m], [ca.trace(m)]), 3)


def test_raw_thread_maps_of_one_function_clash(compiler, tmp_path, monkeypatch):
    """CasADi 3.8 names a thread map's worker after the mapped function: a clear error."""
    rosen = _rosenbrock()

    def no_compiler(*args, **kwargs):
        raise AssertionError("the compiler should not be called")

    monkeypatch.setattr(cg.subprocess, "run", no_compiler)
    with pytest.raises(CompilationError, match="duplicate thread-map workers"):
        compile_functions([rosen.map(2, "thread"), rosen.map(3, "thread")], tmp_path)
    assert (tmp_path / "uuv_ocp_gen.c").is_file()  # kept for inspection


# -- cache -----------------------------------------------------------------------------------


def test_cache_reuses_build(build, monkeypatch):
    mtime = build.path.stat().st_mtime_ns

    def no_compiler(*args, **kwargs):
        raise AssertionError(f"recompiled: {args}")

    monkeypatch.setattr(cg.subprocess, "run", no_compiler)
    again = compile_functions(_test_functions(), build.path.parent, name="test_gen")
    assert again.path == build.path and again.digest == build.digest
    assert again.path.stat().st_mtime_ns == mtime
    assert len(list(build.path.parent.glob("test_gen_*.so"))) == 1


def test_digest_depends_on_flags_and_code(tmp_path):
    rosen = _rosenbrock()
    base = compile_functions([rosen], tmp_path, compile=False)
    other_flags = compile_functions([rosen], tmp_path, compile=False, flags=("-O2",))
    other_code = compile_functions([_pendulum_rk4()], tmp_path, compile=False)
    assert len({base.digest, other_flags.digest, other_code.digest}) == 3


def test_sources_only_needs_no_compiler(tmp_path, monkeypatch):
    monkeypatch.setenv("CC", "/nonexistent")
    result = compile_functions([_rosenbrock()], tmp_path / "new" / "dir", compile=False)
    assert result.path is None and result.functions == {} and result.compiler == ""
    assert result.source.is_file() and result.header.is_file()
    assert "rosen" in result.header.read_text()
    assert not list(result.source.parent.glob("*.so"))


# -- compiler discovery and failures -----------------------------------------------------------


def test_cc_nonexistent(tmp_path, monkeypatch):
    with pytest.raises(CompilerNotFoundError, match="/nonexistent"):
        find_c_compiler({"CC": "/nonexistent", "PATH": os.environ.get("PATH", "")})
    monkeypatch.setenv("CC", "/nonexistent")
    with pytest.raises(CompilerNotFoundError, match="/nonexistent"):
        compile_functions([_rosenbrock()], tmp_path)


def test_empty_path_names_candidates(tmp_path, monkeypatch):
    with pytest.raises(CompilerNotFoundError) as info:
        find_c_compiler({"PATH": ""})
    for candidate in ("cc", "gcc", "clang"):
        assert candidate in str(info.value)
    monkeypatch.delenv("CC", raising=False)
    monkeypatch.setenv("PATH", "")
    with pytest.raises(CompilerNotFoundError, match="cc, gcc, clang"):
        compile_functions([_rosenbrock()], tmp_path)


def test_discovery_order(tmp_path):
    bin_dir = tmp_path / "bin"
    bin_dir.mkdir()
    gcc = _fake_compiler(bin_dir, "gcc")
    clang = _fake_compiler(bin_dir, "clang")
    assert find_c_compiler({"PATH": str(bin_dir)}) == str(gcc)
    assert find_c_compiler({"PATH": str(bin_dir), "CC": "clang"}) == str(clang)
    assert find_c_compiler({"PATH": "", "CC": str(clang)}) == str(clang)
    assert find_c_compiler({"PATH": str(bin_dir), "CC": "  "}) == str(gcc)  # empty = unset


def test_failing_compiler_reports_stderr(tmp_path, monkeypatch):
    script = _fake_compiler(tmp_path)
    monkeypatch.setenv("CC", str(script))
    out = tmp_path / "out"
    with pytest.raises(CompilationError) as info:
        compile_functions([_rosenbrock()], out)
    message = str(info.value)
    assert "fake-cc: fatal error: out of cheese" in message
    assert str(script) in message and "-O3" in message
    assert str(out / "uuv_ocp_gen.c") in message and (out / "uuv_ocp_gen.c").is_file()
    assert not list(out.glob("*.so")) and not list(out.glob(".*")), "debris left behind"


# -- verification --------------------------------------------------------------------------------


def test_verification_detects_wrong_code(compiler, tmp_path, monkeypatch):
    rosen = _rosenbrock()
    x, p = ca.SX.sym("x", DIM), ca.SX.sym("p", 2)
    wrong = ca.Function("rosen", [x, p], [rosen(x, p) * (1 + 1e-9)])
    monkeypatch.setattr(cg.ca, "external", lambda name, path: wrong)
    with pytest.raises(VerificationError, match="rosen"):
        compile_functions([rosen], tmp_path)
    result = compile_functions([rosen], tmp_path, verify=False)
    assert result.max_error == {}


# -- verification of approximate functions (the SIMD kernel's few-ulp sin/cos) ----------------

# sin(K x) moves by about K * ulp(x) ~ 1e-2 when x moves by one ulp: analytically ill-conditioned
K = 1e14


def _mixed(count_ill: int = 1) -> ca.Function:
    """``count_ill`` outputs sin(K x_i) (ill-conditioned), then x1 x2, x1 + x2 and x2 (well-conditioned)."""
    x = ca.SX.sym("x", 3)
    ill = [ca.sin(K * x[i]) for i in range(count_ill)]
    return ca.Function("f", [x], [ca.vertcat(*ill, x[1] * x[2], x[1] + x[2], x[2])])


def _twin(count_ill: int = 1, relative: float = 4 * 2.0**-52, wrong: float = 0.0) -> ca.Function:
    """Return a "compiled" ``_mixed``: sin's argument off by ``relative`` (a few ulp), x1 x2 by ``wrong``."""
    x = ca.SX.sym("x", 3)
    ill = [ca.sin(K * x[i] * (1 + relative)) for i in range(count_ill)]
    return ca.Function("f", [x], [ca.vertcat(*ill, x[1] * x[2] * (1 + wrong), x[1] + x[2], x[2])])


def test_an_approximate_function_is_judged_where_its_twin_is_well_conditioned():
    # a few ulp inside sin(K x) changes the value by ~1e-2: a plain check refuses the twin ...
    with pytest.raises(VerificationError, match="'f' disagrees"):
        cg._verify([_mixed()], {"f": _twin()}, np.random.default_rng(0), 1e-10)
    # ... the conditioning-aware one judges only x1 x2, x1 + x2 and x2, which agree exactly
    errors = cg._verify([_mixed()], {"f": _twin()}, np.random.default_rng(0), 1e-10, approximate={"f"})
    assert errors == {"f": 0.0}


def test_an_approximate_function_still_fails_on_its_well_conditioned_elements():
    twin = _twin(relative=0.0, wrong=1e-9)  # sin exact; x1 x2 wrong by 1e-9 (relative)
    with pytest.raises(VerificationError, match=r"'f' disagrees.*error [0-9.e-]+ > tolerance 1.0e-10"):
        cg._verify([_mixed()], {"f": twin}, np.random.default_rng(0), 1e-10, approximate={"f"})


def test_an_approximate_function_mostly_ill_conditioned_is_refused():
    # 3 of 6 elements judged passes (half), 4 of 7 ill-conditioned does not
    assert cg._verify([_mixed(3)], {"f": _mixed(3)}, np.random.default_rng(0), 1e-10, approximate={"f"})
    four = _mixed(3)
    x = ca.SX.sym("x", 3)
    four = ca.Function("f", [x], [ca.vertcat(four(x), ca.sin(K * x[0] + 1))])
    with pytest.raises(VerificationError, match="cannot be verified.*at 4 of its 7 output elements"):
        cg._verify([four], {"f": four}, np.random.default_rng(0), 1e-10, approximate={"f"})


def test_approximate_must_name_compiled_functions(tmp_path):
    x = ca.SX.sym("x")
    f = ca.Function("f", [x], [x])
    for bad in ("f", ["g"]):
        with pytest.raises(ValueError, match=r"approximate must be a collection of names from \['f'\]"):
            compile_functions([f], tmp_path, compile=False, approximate=bad)


# -- fallback ----------------------------------------------------------------------------------


def test_load_or_fallback_warns_once(tmp_path, monkeypatch):
    monkeypatch.setenv("CC", "/nonexistent")
    functions = _test_functions()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        loaded, library = load_or_fallback(functions, tmp_path)
    runtime = [w for w in caught if issubclass(w.category, RuntimeWarning)]
    assert len(runtime) == 1
    assert "virtual machine" in str(runtime[0].message)
    assert "/nonexistent" in str(runtime[0].message)
    assert library is None
    assert set(loaded) == {f.name() for f in functions}
    assert float(loaded["rosen"](np.ones(DIM), [1.0, 100.0])) == 0.0
    batch = loaded["rosen_batch20"](np.ones((DIM, POPULATION)), [1.0, 100.0])
    assert batch.shape == (1, POPULATION) and float(ca.mmax(ca.fabs(batch))) == 0.0


def test_load_or_fallback_on_compilation_error(tmp_path, monkeypatch):
    monkeypatch.setenv("CC", str(_fake_compiler(tmp_path)))
    with pytest.warns(RuntimeWarning, match="out of cheese"):
        loaded, library = load_or_fallback([_rosenbrock()], tmp_path / "out")
    assert library is None and loaded["rosen"].name() == "rosen"


def test_load_or_fallback_compiled(build):
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        loaded, library = load_or_fallback(_test_functions(), build.path.parent, name="test_gen")
    assert library is not None and library.path == build.path
    assert loaded["rosen"].is_a("External")


def test_concurrent_processes_share_directory(compiler, tmp_path):
    """Several processes building the same library into one directory all succeed."""
    script = (
        "import casadi as ca, sys\n"
        "from uuv_ocp.native.compile import compile_functions\n"
        "x = ca.SX.sym('x', 40)\n"
        "f = ca.Function('race', [x], [ca.sumsqr(ca.sin(x) * x)])\n"
        "lib = compile_functions([f], sys.argv[1], name='race_gen')\n"
        "print(lib.path.name, lib.max_error['race'])\n"
    )
    processes = [
        subprocess.Popen(
            [sys.executable, "-c", script, str(tmp_path)],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        for _ in range(4)
    ]
    outputs = [process.communicate(timeout=60) for process in processes]
    assert all(process.returncode == 0 for process in processes), outputs
    assert len({out.split()[0] for out, _ in outputs}) == 1
    assert len(list(tmp_path.glob("race_gen_*.so"))) == 1
    assert not list(tmp_path.glob(".*")), "temporary files left behind"
