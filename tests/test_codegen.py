"""C code generation: compiled = symbolic, cache, all-C IGWO = Python IGWO, standalone C program."""

import re
import stat
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import uuv_ocp as uo
from tests.conftest import needs_compiler
from tests.helpers_c import build_and_run
from uuv_ocp import codegen
from uuv_ocp.optimize import minimize

EXAMPLES = Path(__file__).resolve().parents[1] / "examples" / "c"


@pytest.fixture(autouse=True)
def private_cache(tmp_path, monkeypatch):
    monkeypatch.setenv("UUV_OCP_CACHE", str(tmp_path / "cache"))


CASES = [
    (uo.Vehicle.rexrov(), "s2", "equality", None),
    (uo.Vehicle.rexrov_controller_model(), "s8", "cost", None),
    (uo.Vehicle.rexrov(), "s8", "none", 0.1),
    (uo.Vehicle.rexrov_controller_model(), "s2", "equality", 0.05),
]


@needs_compiler
@pytest.mark.parametrize(("vehicle", "name", "terminal", "tube"), CASES)
def test_compiled_functions_equal_symbolic(tmp_path, vehicle, name, terminal, tube):
    problem = uo.TrackingProblem(
        vehicle, uo.Reference.paper(name), horizon=6, terminal=terminal, position_tube=tube
    )
    generated = codegen.generate_c(problem, tmp_path, population=8)
    symbolic = codegen.symbolic_functions(problem, population=8)
    rng = np.random.default_rng(11)
    for function_name, compiled in generated.functions.items():
        reference = symbolic[function_name]
        inputs = [rng.normal(size=reference.size_in(i)) for i in range(reference.n_in())]
        expected = reference.call(inputs)
        actual = compiled.call(inputs)
        for want, got in zip(expected, actual, strict=True):
            np.testing.assert_allclose(np.array(got), np.array(want), rtol=1e-12, atol=1e-12)
    assert max(generated.max_error.values()) <= 1e-12


@needs_compiler
def test_builds_are_cached_by_content(tmp_path):
    problem = uo.TrackingProblem(uo.Vehicle.rexrov(), uo.Reference.paper("s2"), horizon=4)
    first = codegen.generate_c(problem, tmp_path, population=4)
    stamp = first.library.stat().st_mtime_ns
    second = codegen.generate_c(problem, tmp_path, population=4)
    assert not first.reused and second.reused
    assert second.library == first.library and second.library.stat().st_mtime_ns == stamp
    other = codegen.generate_c(problem.replace(dt=0.05), tmp_path, population=4)
    assert other.library != first.library


@needs_compiler
def test_all_c_igwo_step_starts_from_the_virtual_machines_fitness(s2_problem, feasible_start):
    """All-C vs the Python IGWO on the virtual machine: same initial pack, same fitness.

    Same up to the SIMD kernel's sin/cos rounding.  (Bit-identity with the Python IGWO on the
    same compiled kernel is tested in native/test_simd.py.)
    """
    x0, t0 = feasible_start
    p = s2_problem.parameters(x0, t0)
    python = uo.get_solver(s2_problem, "igwo", {"seed": 0})
    native = uo.get_solver(s2_problem, "igwo", {"seed": 0, "compiled": True})
    assert native.native is not None
    for seed in (1, 2):
        expected = python.solve(p, None, np.random.default_rng(seed))
        actual = native.solve(p, None, np.random.default_rng(seed))
        np.testing.assert_allclose(actual.history[0], expected.history[0], rtol=1e-13)
        assert actual.history[-1] <= actual.history[0]


@needs_compiler
def test_standalone_c_program_matches_score(tmp_path):
    sys.path.insert(0, str(EXAMPLES))
    try:
        from write_input import write_input
    finally:
        sys.path.pop(0)
    data = write_input(tmp_path / "input.txt", seed=4)
    problem, p = data["problem"], data["p"]
    generated = codegen.generate_c(problem, tmp_path / "build", functions=("cost", "cost_batch"))
    # the program sits next to the library and finds it through $ORIGIN: no hand declaration
    # of uuv_ocp_igwo (the generated header has it) and no dependence on the working directory
    output = build_and_run(
        EXAMPLES / "main.c", [generated.library], generated.directory, tmp_path / "input.txt", tmp_path
    )
    values = dict(re.findall(r"^(\w+) (\S+)$", output, flags=re.MULTILINE))
    assert float(values["cost"]) == pytest.approx(data["score"], rel=1e-12)
    assert float(values["penalty"]) == pytest.approx(data["penalty"], rel=1e-12)
    # the same data through the Python IGWO (compiled fitness) gives the same best fitness
    fitness = generated["cost_batch"]
    result = minimize(
        lambda x: np.array(fitness(x.T, p)).ravel(),
        -np.ones(problem.control_dim),
        np.ones(problem.control_dim),
        "igwo",
        seed=4,
    )
    assert float(values["igwo_best_fitness"]) == result.fun


def test_missing_compiler_is_named(monkeypatch):
    monkeypatch.setenv("CC", "/nonexistent/cc")
    with pytest.raises(codegen.CompilerNotFoundError, match="/nonexistent/cc"):
        codegen.find_c_compiler()
    monkeypatch.delenv("CC")
    monkeypatch.setenv("PATH", "")
    with pytest.raises(codegen.CompilerNotFoundError, match="cc, gcc, clang"):
        codegen.find_c_compiler()


def test_compiled_swarm_falls_back_to_the_virtual_machine_with_one_warning(
    monkeypatch, s2_problem, feasible_start
):
    monkeypatch.setenv("CC", "/nonexistent/cc")
    # builds and backends are cached by content, and this one is built without a compiler:
    # a problem no other test uses keeps its VM fallback out of their caches
    problem = s2_problem.replace(horizon=s2_problem.horizon - 1)
    with pytest.warns(RuntimeWarning, match="virtual machine") as record:
        solver = uo.get_solver(problem, "igwo", {"compiled": True})
        uo.get_solver(problem, "gwo", {"compiled": True, "population": 20})
    assert len(record) == 1
    assert solver.native is None
    x0, t0 = feasible_start
    reference = uo.solve(problem, "igwo", x0=x0, t0=t0)
    fallback = uo.solve(problem, "igwo", x0=x0, t0=t0, options={"compiled": True})
    np.testing.assert_array_equal(fallback.controls, reference.controls)


def test_compiler_errors_show_the_compiler_output(tmp_path, monkeypatch):
    fake = tmp_path / "fakecc"
    fake.write_text("#!/bin/sh\necho 'fatal: synthetic failure' >&2\nexit 1\n")
    fake.chmod(fake.stat().st_mode | stat.S_IEXEC)
    monkeypatch.setenv("CC", str(fake))
    problem = uo.TrackingProblem(uo.Vehicle.rexrov(), uo.Reference.paper("s2"), horizon=3)
    with pytest.raises(codegen.CompilationError, match="synthetic failure"):
        codegen.generate_c(problem, tmp_path / "out", population=4)


def test_bad_arguments_raise(tmp_path, s2_problem):
    with pytest.raises(ValueError, match="functions"):
        codegen.generate_c(s2_problem, tmp_path, functions=("solver",))
    with pytest.raises(ValueError, match="population"):
        codegen.generate_c(s2_problem, tmp_path, population=0)


def test_two_prefixed_problems_link_into_one_program(tmp_path):
    """Every exported symbol carries the prefix: two problems' libraries in one C program."""
    problems = {
        "s2_": uo.TrackingProblem(uo.Vehicle.rexrov(), uo.Reference.paper("s2"), horizon=5, dt=0.1),
        "s5_": uo.TrackingProblem(uo.Vehicle.rexrov(), uo.Reference.paper("s5"), horizon=7, dt=0.1),
    }
    rng = np.random.default_rng(2)
    builds, expected, lines = {}, {}, ["#include <stdio.h>"]
    for prefix, problem in problems.items():
        build = codegen.generate_c(problem, tmp_path / prefix, functions=("cost",), prefix=prefix)
        builds[prefix] = build
        exported = subprocess.run(
            ["nm", "-D", "--defined-only", str(build.library)], capture_output=True, text=True
        ).stdout.split()[2::3]
        assert exported and all(symbol.startswith(prefix) for symbol in exported), exported
        lines.append(f'#include "{build.header}"')
        controls = rng.uniform(-0.5, 0.5, problem.control_dim)
        x0 = problem.reference.evaluate([1.0])[0]
        p = problem.parameters(x0, 1.0)
        expected[prefix] = float(problem.build().cost(controls, p)[0])
        lines.append(f"static const double {prefix}U[] = {{{', '.join(repr(float(v)) for v in controls)}}};")
        lines.append(f"static const double {prefix}P[] = {{{', '.join(repr(float(v)) for v in p)}}};")
    lines.append("int main(void) {")
    for prefix in problems:
        lines += [
            "  {",
            "    double f = 0, g = 0, w[100000]; casadi_int iw[1000];",
            f"    const double* arg[8] = {{{prefix}U, {prefix}P}}; double* res[8] = {{&f, &g}};",
            f"    if ({prefix}cost(arg, res, iw, w, 0)) return 1;",
            f'    printf("{prefix} %.17g\\n", f);',
            "  }",
        ]
    lines += ["  return 0;", "}"]
    (tmp_path / "both.c").write_text("\n".join(lines) + "\n")
    program = tmp_path / "both"
    command = [codegen.find_c_compiler(), "-Werror=implicit-function-declaration", str(tmp_path / "both.c")]
    command += [str(build.library) for build in builds.values()]
    command += [f"-Wl,-rpath,{build.directory}" for build in builds.values()] + ["-lm", "-o", str(program)]
    subprocess.run(command, check=True, capture_output=True, text=True)
    output = subprocess.run([str(program)], check=True, capture_output=True, text=True).stdout
    values = dict(line.split() for line in output.splitlines())
    for prefix, value in expected.items():
        assert float(values[prefix]) == pytest.approx(value, rel=1e-12)
    assert expected["s2_"] != pytest.approx(expected["s5_"])  # two different problems


def test_bad_prefix_is_named(tmp_path, s2_problem):
    with pytest.raises(ValueError, match="prefix"):
        codegen.generate_c(s2_problem, tmp_path, functions=("cost",), prefix="2-bad")
