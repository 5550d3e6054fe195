"""DESIGN §3: the public API as documented, run at small sizes."""

import casadi as ca
import numpy as np

import uuv_ocp as uo


def test_design_section_3_snippet(tmp_path):
    vehicle = uo.Vehicle.rexrov()
    vehicle = uo.Vehicle(
        mass=1862.9,
        inertia=691.2,
        added_mass=(779.8, 1222.0, 224.3),
        linear_damping=(74.8, 69.5, 105.0),
        quadratic_damping=(748.2, 992.5, 523.3),
        max_thrust=(2000.0, 2000.0, 1400.0),
        max_thrust_rate=(4000.0, 4000.0, 2800.0),
    )
    ref = uo.Reference.paper("s2")
    ref = uo.Reference.from_xy(lambda t: 0.5 * t, lambda t: 2 * ca.sin(0.5 * t), name="sine")
    problem = uo.TrackingProblem(vehicle, ref, horizon=10, dt=0.1, terminal="equality")
    x0 = ref.initial_state(t0=0.0)
    assert x0.shape == (6,)

    res = uo.solve(problem, "ipopt", x0=x0, t0=0.0)
    assert res.controls.shape == (10, 3) and res.states.shape == (11, 6)
    assert (res.cost, res.max_violation) == uo.score(problem, res.controls, x0=x0, t0=0.0)
    for attribute in ("success", "status", "solve_time", "iterations", "evaluations", "solver"):
        assert hasattr(res, attribute)
    assert {"fatrop", "gwo", "igwo", "igwo+ipopt", "ipopt", "pso", "sqp", "ssa"} <= set(
        uo.available_solvers()
    )

    best = uo.minimize(
        lambda X: np.sum(X**2, axis=1),
        -np.ones(4),
        np.ones(4),
        method="igwo",
        population=20,
        iterations=30,
        seed=1,
    )
    assert best.x.shape == (4,) and best.fun >= 0 and best.history.size == 31 and best.evaluations == 620

    mpc = uo.NMPC(problem, solver="igwo", seed=1, options={"population": 8, "iterations": 4})
    run = uo.simulate(mpc, x0=x0, duration=0.5, current=uo.Current(speed=0.3, direction=0.5), seed=1)
    for attribute in ("t", "states", "controls", "reference", "solve_times", "failures"):
        assert hasattr(run, attribute)
    assert "max_abs_ex" in run.metrics()

    generated = uo.generate_c(problem, tmp_path / "cost")
    assert generated.library.exists()
    table = uo.compare(problem, ["ipopt", "sqp", "igwo"], x0=x0, seed=1)
    assert [row.solver for row in table] == ["ipopt", "sqp", "igwo"]
