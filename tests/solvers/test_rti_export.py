"""Generated exact NMPC in C (``generate_c(..., functions=(..., "nmpc_step"))``)."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

import uuv_ocp as uo
from tests.helpers_c import build_and_run
from uuv_ocp import codegen
from uuv_ocp.native.hpipm import HPIPM_ENV
from uuv_ocp.solvers.result import Iterate
from uuv_ocp.solvers.rti import nmpc_step_function

EXAMPLES = Path(__file__).resolve().parents[2] / "examples" / "c"


@pytest.mark.slow
def test_generated_nmpc_closed_loop_equals_python(tmp_path, monkeypatch):
    """The C closed loop (examples/c/nmpc_loop.c) = the Python sqp-rti loop, step by step.

    On the CasADi wheel's HPIPM, which a fresh machine links: the build's check against the
    conic HPIPM path failed there (1.2e-4 > 1e-4, a QP HPIPM's speed mode did not solve) and
    passed once the suite's native HPIPM test had built a native HPIPM into the shared cache.
    """
    try:
        codegen.find_c_compiler()
    except codegen.CompilerNotFoundError:
        pytest.skip("no C compiler")
    monkeypatch.setenv(HPIPM_ENV, "wheel")  # not whatever native build the cache holds
    problem = uo.TrackingProblem(uo.Vehicle.rexrov(), uo.Reference.paper("s2"), horizon=20, dt=0.1)
    generated = codegen.generate_c(problem, tmp_path / "build", functions=("model_step", "nmpc_step"))
    # the build's own check: 100 random states against the Python backend
    assert generated.max_error["nmpc_step"] <= 1e-9
    # and against the same step on CasADi's conic HPIPM interface (a second QP solver); measured
    # 7.6e-8, it was 1.2e-4 before a QP HPIPM did not solve was solved again in robust mode
    assert generated.max_error["nmpc_step_conic"] <= codegen.NMPC_CONIC_TOLERANCE
    _, backend = nmpc_step_function(problem)
    variant = "soft" if "soft" in backend.variants else "hard"
    spec = problem.spec()
    step = problem.build().step
    x = problem.reference.initial_state(0.0) + np.array([0.3, -0.2, 0.05, 0.0, 0.0, 0.0])
    u_prev = np.zeros(3)
    p = problem.parameters(x, 0.0, u_prev)
    states, scaled = problem.initial_guess(p)
    w = backend.compose_primal(variant, states, scaled, problem.previous_scaled(p))
    first = (x.copy(), u_prev.copy(), w.copy())
    steps, windows, controls = 15, [], []
    for k in range(steps):
        p = problem.parameters(x, k * problem.dt, u_prev)
        windows.append(p)
        result = backend.solve(p, Iterate(scaled_controls=scaled, states=states, primal=w, variant=variant))
        assert result.success
        u = result.controls[0]
        controls.append(u)
        data = backend.variants[variant]
        w = result.iterate.primal[data.primal_shift]
        x = np.array(step(x, u, np.zeros(step.numel_in(2)), np.zeros(step.numel_in(3)))).ravel()
        u_prev = u
    lines = [f"{spec.state_dim} {spec.control_size} {windows[0].size} {first[2].size} {steps}"]
    lines += [" ".join(repr(float(v)) for v in block) for block in first]
    lines += [" ".join(repr(float(v)) for v in window) for window in windows]
    (tmp_path / "loop.txt").write_text("\n".join(lines) + "\n")
    output = build_and_run(
        EXAMPLES / "nmpc_loop.c",
        [generated.nmpc_library, generated.library],
        generated.directory,
        tmp_path / "loop.txt",
        tmp_path,
    )
    rows = [line.split()[2:] for line in output.splitlines() if re.match(r"^step \d+", line)]
    c_controls = np.array([[float(v) for v in row[:3]] for row in rows])
    assert c_controls.shape == (steps, 3)
    span = spec.upper - spec.lower
    np.testing.assert_allclose(c_controls / span, np.array(controls) / span, rtol=0, atol=1e-9)
