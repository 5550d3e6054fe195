"""Non-convex problems: two homotopy classes, the hybrid's warm start, multi-start, obstacles.

Every expected value is computed here independently: the two sides' optima by forcing the exact
solvers into each side with an extra constraint, distances and moving centres in numpy.
"""

from __future__ import annotations

import importlib.util
import math
import sys
from pathlib import Path

import casadi as ca
import numpy as np
import pytest

import uuv_ocp as uo
from uuv_ocp.solvers.result import Iterate

# ------------------------------------------------------------------ the two-homotopy instance
# A double integrator tracks the straight line from (0, 0) to (10, 0) past one disc of radius
# 1.2 m (+ 0.1 m margin) centred 0.1 m above the line: the line passes below the centre, so a
# gradient solver started on it is pushed below.  The vehicle starts with 0.6 m/s upward, which
# makes passing above cheaper (measured: 3.433 above, 3.748 below).
HORIZON, DT = 30, 0.25
CENTRE, RADIUS, MARGIN = np.array([5.0, 0.1]), 1.2, 0.1
GOAL = np.array([10.0, 0.0])
LINE = np.linspace(0.0, 1.0, HORIZON + 1)[:, None] * GOAL
SPEED = GOAL / (HORIZON * DT)
X0 = np.array([0.0, 0.0, SPEED[0], 0.6])


def two_homotopy_ocp() -> uo.Ocp:
    ocp = uo.Ocp(horizon=HORIZON, dt=DT, name="two_homotopy")
    pos = ocp.state("pos", 2)
    vel = ocp.state("vel", 2)
    acc = ocp.control("acc", 2, lower=-1.0, upper=1.0, max_rate=2.0)
    line = ocp.parameter("line", 2, stagewise=True)
    side = ocp.parameter("side", stagewise=True)  # +1 / -1 forces y_k >= 0 / <= 0 on that node
    ocp.set_der(pos, vel)
    ocp.set_der(vel, acc)
    ocp.add_stage_cost(residual=ca.vertcat(0.3 * (pos - line), 0.5 * acc), start=1)
    ocp.add_terminal_cost(residual=ca.vertcat(3.0 * (pos - ca.DM(GOAL)), vel))
    ocp.subject_to(uo.Obstacle.circle(tuple(CENTRE), RADIUS, margin=MARGIN).clearance(pos) >= 0)
    ocp.subject_to(side * pos[1] >= 0)
    return ocp


@pytest.fixture(scope="module")
def two_homotopy() -> uo.Ocp:
    return two_homotopy_ocp()


def data(node: int | None = None, side: float = 0.0) -> dict:
    sides = np.zeros(HORIZON + 1)
    if node is not None:
        sides[node] = side
    return {"line": LINE, "side": sides}


def line_guess(lateral: float = 0.0) -> Iterate:
    """States on the straight line (optionally bent sideways by ``lateral`` m mid-way), zero controls."""
    states = np.column_stack([LINE, np.tile(SPEED, (HORIZON + 1, 1))])
    states[:, 1] += lateral * np.sin(np.linspace(0.0, math.pi, HORIZON + 1))
    states[0] = X0
    return Iterate(scaled_controls=np.zeros((HORIZON, 2)), states=states)


def nearest_node(states: np.ndarray) -> int:
    return int(np.argmin(np.linalg.norm(states[:, :2] - CENTRE, axis=1)))


def assert_clear_of_the_disc(states: np.ndarray) -> None:
    distance = np.linalg.norm(states[1:, :2] - CENTRE, axis=1)  # nodes 1..N (x_0 is given)
    assert np.all(distance >= RADIUS + MARGIN - 1e-6), distance.min()


def forced_side_costs(ocp: uo.Ocp, node: int) -> dict[float, float]:
    """Solve for the optimum on each side: ipopt and fatrop, forced by ``±y_node >= 0``, from a bent guess."""
    costs = {}
    for side in (1.0, -1.0):
        found = []
        for solver in ("ipopt", "fatrop"):
            res = uo.solve(ocp, solver, x0=X0, parameters=data(node, side), warm_start=line_guess(side * 1.8))
            assert res.success, (solver, side, res.status)
            assert side * res.states[node, 1] >= -1e-6
            assert_clear_of_the_disc(res.states)
            found.append(res.cost)
        assert found[0] == pytest.approx(found[1], rel=1e-6)  # two solvers, one optimum per side
        costs[side] = found[0]
    return costs


def test_exact_solver_from_the_line_ends_on_the_worse_side_and_the_hybrid_on_the_better(two_homotopy):
    ocp = two_homotopy
    trapped = {}
    for solver in ("fatrop", "ipopt"):
        res = uo.solve(ocp, solver, x0=X0, parameters=data(), warm_start=line_guess())
        assert res.success, res.status
        assert_clear_of_the_disc(res.states)
        trapped[solver] = res
    node = nearest_node(trapped["fatrop"].states)
    assert trapped["fatrop"].states[node, 1] < 0 and trapped["ipopt"].states[node, 1] < 0  # below
    costs = forced_side_costs(ocp, node)
    assert costs[1.0] < 0.95 * costs[-1.0]  # above is better by more than 5 %
    for res in trapped.values():
        assert res.cost == pytest.approx(costs[-1.0], rel=1e-6)  # the worse side's optimum
    hybrid = uo.solve(ocp, "igwo+fatrop", x0=X0, parameters=data(), warm_start=line_guess())
    assert hybrid.success, hybrid.status
    assert hybrid.states[nearest_node(hybrid.states), 1] > 0  # above
    assert hybrid.cost == pytest.approx(costs[1.0], rel=1e-6)  # the better side's optimum
    assert_clear_of_the_disc(hybrid.states)


# ------------------------------------------------------------------ candidates=k
def search_coordinates(plan: np.ndarray) -> np.ndarray:
    """Invert decode: W of a scaled plan, z_k = lo + (w + 1)/2 (hi - lo) on box ∩ rate box."""
    previous, out = np.zeros(2), []
    for z in plan:
        low, high = np.maximum(-1.0, previous - 2.0 * DT), np.minimum(1.0, previous + 2.0 * DT)
        out.append(2.0 * (z - low) / (high - low) - 1.0)
        previous = z
    return np.array(out)


def test_candidates_start_the_exact_solver_from_distinct_swarm_plans(two_homotopy):
    ocp = two_homotopy
    p = ocp.parameters(X0, data())
    swarm = uo.solve(ocp, "pso", x0=X0, parameters=data(), options={"candidates": 3, "seed": 4})
    plans = swarm.details["candidates"]
    assert len(plans) == 3 and len(swarm.details["candidate_fitness"]) == 3
    np.testing.assert_allclose(plans[0], swarm.iterate.scaled_controls)  # the best plan first
    assert swarm.details["candidate_fitness"] == sorted(swarm.details["candidate_fitness"])
    paths = [ocp.rollout(ocp.controls_from_scaled(plan), p)[1:, :2] for plan in plans]
    for i in range(3):
        rate = np.abs(np.diff(np.vstack([np.zeros(2), plans[i]]), axis=0))
        assert np.all(np.abs(plans[i]) <= 1.0) and np.all(rate <= 2.0 * DT + 1e-12)
        for j in range(i):
            assert np.sqrt(np.mean((paths[i] - paths[j]) ** 2)) > 0.05  # distinct paths (m)
    # nothing is farther than 1e9 (state spreads): only the best plan is a candidate
    lone = uo.solve(
        ocp, "pso", x0=X0, parameters=data(), options={"candidates": 3, "candidate_distance": 1e9}
    )
    assert len(lone.details["candidates"]) == 1
    # the "controls" metric: pairwise RMS distance of the search coordinates W, inverted here
    by_w = uo.solve(
        ocp,
        "pso",
        x0=X0,
        parameters=data(),
        options={"candidates": 4, "seed": 4, "candidate_metric": "controls", "candidate_distance": 0.3},
    )
    coordinates = [search_coordinates(plan) for plan in by_w.details["candidates"]]
    assert len(coordinates) == 4
    for i in range(4):
        for j in range(i):
            assert np.sqrt(np.mean((coordinates[i] - coordinates[j]) ** 2)) > 0.3
    hybrid = uo.solve(
        ocp,
        "pso+fatrop",
        x0=X0,
        parameters=data(),
        options={"candidates": 3, "swarm": {"seed": 4}, "keep_warm_start": False},
    )
    rows = hybrid.details["candidates"]
    assert len(rows) == 3 and [row["start"] for row in rows] == ["swarm 0", "swarm 1", "swarm 2"]
    # each row is fatrop started from that plan with the states of its rollout, solved here again
    for row, plan in zip(rows, plans, strict=True):
        guess = Iterate(scaled_controls=plan, states=ocp.rollout(ocp.controls_from_scaled(plan), p))
        alone = uo.solve(ocp, "fatrop", x0=X0, parameters=data(), warm_start=guess)
        assert row["cost"] == pytest.approx(alone.cost, rel=1e-9) and row["success"] == alone.success
    feasible = [row["cost"] for row in rows if row["success"]]
    assert hybrid.cost == pytest.approx(min(feasible), rel=1e-12)
    assert rows[hybrid.details["chosen"]]["cost"] == hybrid.cost
    # k = 1 (default) is the plain hybrid: no candidate bookkeeping at all
    plain = uo.solve(ocp, "pso+fatrop", x0=X0, parameters=data(), options={"swarm": {"seed": 4}})
    assert "candidates" not in plain.details
    assert plain.cost == pytest.approx(rows[0]["cost"], rel=1e-9)
    assert "candidates" not in uo.solve(ocp, "pso", x0=X0, parameters=data()).details
    with pytest.raises(ValueError, match="candidates"):
        uo.get_solver(ocp, "igwo+fatrop", {"candidates": 0})
    with pytest.raises(ValueError, match="candidate_metric"):
        uo.get_solver(ocp, "igwo", {"candidates": 2, "candidate_metric": "paths"})


def test_the_kept_warm_start_is_the_second_start_so_the_hybrid_never_loses_to_the_plain_solver(two_homotopy):
    """Three starts with keep_warm_start (default): the swarm's best, the caller's guess, its second."""
    ocp = two_homotopy
    p = ocp.parameters(X0, data())
    # a guess bent below the disc: plain fatrop stays on that (worse) side, the swarm's best goes above
    guess = line_guess(-1.8)
    plain = uo.solve(ocp, "fatrop", x0=X0, parameters=data(), warm_start=guess)
    swarm = uo.solve(
        ocp, "pso", x0=X0, parameters=data(), warm_start=guess, options={"candidates": 3, "seed": 4}
    )
    hybrid = uo.solve(
        ocp,
        "pso+fatrop",
        x0=X0,
        parameters=data(),
        warm_start=guess,
        options={"candidates": 3, "swarm": {"seed": 4}},
    )
    rows = hybrid.details["candidates"]
    assert [row["start"] for row in rows] == ["swarm 0", "warm start", "swarm 1"]
    assert rows[1]["swarm_fitness"] is None
    assert rows[1]["cost"] == pytest.approx(plain.cost, rel=1e-9) and rows[1]["success"] == plain.success
    for row, plan in zip([rows[0], rows[2]], swarm.details["candidates"][:2], strict=True):
        start = Iterate(scaled_controls=plan, states=ocp.rollout(ocp.controls_from_scaled(plan), p))
        alone = uo.solve(ocp, "fatrop", x0=X0, parameters=data(), warm_start=start)
        assert row["cost"] == pytest.approx(alone.cost, rel=1e-9)
    assert plain.success and hybrid.success
    assert plain.states[nearest_node(plain.states), 1] < 0 < rows[0]["cost"] < plain.cost
    assert hybrid.cost <= plain.cost * (1 + 1e-9)
    assert hybrid.cost == pytest.approx(min(row["cost"] for row in rows if row["success"]), rel=1e-12)
    with pytest.raises(ValueError, match="keep_warm_start"):
        uo.get_solver(ocp, "pso+fatrop", {"candidates": 2, "keep_warm_start": "yes"})


def test_without_the_kept_warm_start_the_hybrid_loses_where_the_guess_is_in_the_better_class(two_homotopy):
    """A guess above the disc (the better side) whose controls push down; a tiny swarm goes below.

    Plain fatrop from the guess reaches the better side; the swarm's only plan (candidates
    farther than 1e9 apart: one) leads fatrop below.  Keeping the warm start recovers the
    plain solver's optimum, the swarm's plans alone do not.
    """
    ocp = two_homotopy
    controls = np.zeros((HORIZON, 2))
    controls[:, 1] = -1.0
    guess = Iterate(scaled_controls=controls, states=line_guess(2.5).states)
    plain = uo.solve(ocp, "fatrop", x0=X0, parameters=data(), warm_start=guess)
    assert plain.success and plain.states[nearest_node(plain.states), 1] > 0  # above: the better side
    options = {
        "candidates": 2,
        "candidate_distance": 1e9,
        "swarm": {"population": 4, "iterations": 1, "seed": 0},
    }
    alone = uo.solve(
        ocp,
        "igwo+fatrop",
        x0=X0,
        parameters=data(),
        warm_start=guess,
        options={**options, "keep_warm_start": False},
    )
    kept = uo.solve(ocp, "igwo+fatrop", x0=X0, parameters=data(), warm_start=guess, options=options)
    assert alone.states[nearest_node(alone.states), 1] < 0 and alone.cost > 1.05 * plain.cost
    assert [row["start"] for row in kept.details["candidates"]] == ["swarm 0", "warm start"]
    assert kept.cost == pytest.approx(plain.cost, rel=1e-9)


# ------------------------------------------------------------------ terminal strategy
def test_hybrid_keeps_the_sticky_terminal_strategy_across_steps():
    """A goal out of reach: the hybrid's exact stage is relaxed, the next steps start soft."""
    ocp = uo.Ocp(horizon=10, dt=0.1)
    pos = ocp.state("pos")
    vel = ocp.state("vel")
    acc = ocp.control("acc", lower=-1.0, upper=1.0, max_rate=20.0)
    goal = ocp.parameter("goal")
    ocp.set_der(pos, vel)
    ocp.set_der(vel, acc)
    ocp.add_stage_cost(residual=ca.vertcat(pos - goal, 0.1 * acc))
    ocp.subject_to(pos == goal, at="terminal")  # 3 m in 1 s at 1 m/s² from rest: infeasible
    controller = uo.NMPC(ocp, "pso+fatrop", options={"swarm": {"population": 8, "iterations": 5}}, seed=1)
    state, control = np.zeros(2), np.zeros(1)
    attempts = []
    for _ in range(3):
        out = controller.step(state, u_prev=control, parameters={"goal": 3.0})
        assert not out.fallback and out.result.terminal_relaxed
        attempts.append([attempt[0] for attempt in out.result.details["attempts"]])
        control = out.control
        state = state + 0.1 * np.array([state[1], control[0]])
    assert attempts == [["hard", "soft"], ["soft"], ["soft"]]


# ------------------------------------------------------------------ multistart
def test_multistart_finds_the_better_side_from_its_structured_starts(two_homotopy):
    ocp = two_homotopy
    plain = uo.solve(ocp, "ipopt", x0=X0, parameters=data(), warm_start=line_guess())
    res = uo.solve(ocp, "multistart-ipopt", x0=X0, parameters=data(), warm_start=line_guess())
    rows = res.details["starts"]
    labels = [row["start"] for row in rows]
    assert labels[:6] == ["default", "held", "+50% acc[0]", "-50% acc[0]", "+50% acc[1]", "-50% acc[1]"]
    assert labels[6:] == ["random 0", "random 1"]  # 8 starts by default
    assert rows[0]["cost"] == pytest.approx(plain.cost, rel=1e-9)  # "default" = the plain solve
    assert res.cost == pytest.approx(min(r["cost"] for r in rows if r["success"]), rel=1e-12)
    assert res.cost < 0.95 * plain.cost  # the better side, found by another start
    assert res.states[nearest_node(res.states), 1] > 0
    assert res.solver == "multistart-ipopt"
    assert res.solve_time >= sum(row["time"] for row in rows)
    # seeded: the same seed gives the same random starts, another seed other random ones
    backend = uo.get_solver(ocp, "multistart-fatrop", {"starts": 10, "seed": 3})
    p = ocp.parameters(X0, data())
    first = backend.guesses(p, None, None)
    again = backend.guesses(p, None, None)
    other = backend.guesses(p, None, np.random.default_rng(99))
    assert len(first) == 10 and first[0] == ("default", None)
    for (label, a), (_, b), (_, c) in zip(first[1:], again[1:], other[1:], strict=True):
        np.testing.assert_array_equal(a.scaled_controls, b.scaled_controls)
        assert label.startswith("random") != np.array_equal(a.scaled_controls, c.scaled_controls)
        # every start holds the box and the rate bound (u_prev = 0), its states are its rollout
        rate = np.abs(np.diff(np.vstack([np.zeros(2), a.scaled_controls]), axis=0))
        assert np.all(np.abs(a.scaled_controls) <= 1.0) and np.all(rate <= 2.0 * DT + 1e-12)
        np.testing.assert_allclose(a.states, ocp.rollout(ocp.controls_from_scaled(a.scaled_controls), p))


def test_multistart_names_exist_for_every_exact_backend_and_make_no_hybrids():
    names = uo.available_solvers()
    assert {"multistart-ipopt", "multistart-fatrop", "multistart-sqp"} <= set(names)
    assert not any("+multistart" in name for name in names)
    assert uo.solvers.REGISTRY.kind("multistart-sqp") == "multistart"
    with pytest.raises(ValueError, match="solver must be one of"):
        uo.solvers.REGISTRY.factory("igwo+multistart-ipopt")
    with pytest.raises(ValueError, match="solver must be one of"):
        uo.solvers.REGISTRY.factory("multistart-igwo")  # a swarm is not an exact backend

    class Plugin(uo.solvers.SqpSolver):
        """A plug-in exact backend."""

    uo.register_solver("plugin-sqp", Plugin, kind="exact", overwrite=True)
    try:
        assert "multistart-plugin-sqp" in uo.available_solvers()
        ocp = two_homotopy_ocp()
        backend = uo.get_solver(ocp, "multistart-plugin-sqp", {"starts": 2})
        assert isinstance(backend.exact, Plugin) and backend.starts == 2
    finally:
        uo.solvers.REGISTRY._factories.pop("plugin-sqp")
    with pytest.raises(ValueError, match="starts"):
        uo.get_solver(two_homotopy_ocp(), "multistart-ipopt", {"starts": 0})
    with pytest.raises(ValueError, match="unknown options"):
        uo.get_solver(two_homotopy_ocp(), "multistart-ipopt", {"start": 3})


# ------------------------------------------------------------------ obstacles
def test_moving_obstacle_centres_follow_their_path_and_the_plan_keeps_clear():
    reference = uo.Reference.from_xy(lambda t: 0.5 * t, lambda t: 0 * t, name="line", t_end=30.0)
    crossing = uo.Obstacle.moving(lambda t: (3.0 + 0 * t, -2.1 + 0.3 * t), 0.3, margin=0.1)
    fixed = uo.Obstacle.circle((2.8, 1.0), 0.4, margin=0.1)
    problem = uo.TrackingProblem(uo.Vehicle.rexrov(), reference, terminal="cost", obstacles=[crossing, fixed])
    t0 = 4.5
    x0 = reference.evaluate([t0])[0]
    p = problem.parameters(x0, t0)
    times = t0 + problem.dt * np.arange(problem.horizon + 1)
    expected = np.column_stack([np.full(times.size, 3.0), -2.1 + 0.3 * times])  # the path, in numpy
    part = problem.spec().layout.entries["obstacle0"][0]
    np.testing.assert_allclose(p[part].reshape(-1, 2), expected, rtol=0, atol=1e-12)
    assert "obstacle1" not in problem.spec().layout.entries  # a fixed obstacle is no parameter
    free = uo.solve(problem.replace(obstacles=()), "ipopt", x0=x0, t0=t0)
    assert np.min(np.linalg.norm(free.states[1:, :2] - expected[1:], axis=1)) < 0.4 - 0.1  # it would hit
    for solver in ("ipopt", "fatrop"):
        res = uo.solve(problem, solver, x0=x0, t0=t0)
        assert res.success, res.status
        moving = np.linalg.norm(res.states[1:, :2] - expected[1:], axis=1)
        still = np.linalg.norm(res.states[1:, :2] - [2.8, 1.0], axis=1)
        assert np.all(moving >= 0.3 + 0.1 - 1e-6) and np.all(still >= 0.4 + 0.1 - 1e-6)
        assert np.min(moving) < 0.4 + 1e-3  # the constraint is active: the plan dodges it


def test_closest_approach_rejects_what_is_not_obstacles_and_a_run():
    from uuv_ocp.obstacles import closest_approach

    rock = uo.Obstacle.circle((1.0, 0.0), 0.5)
    with pytest.raises(ValueError, match="obstacles must be a non-empty list"):
        closest_approach([], object())
    with pytest.raises(ValueError, match="obstacles must be a non-empty list"):
        closest_approach([rock, "rock"], object())
    with pytest.raises(ValueError, match="run must be a uuv_ocp.ClosedLoopResult"):
        closest_approach([rock], np.zeros((3, 4)))


def test_bad_obstacles_raise_naming_the_argument():
    with pytest.raises(ValueError, match="radius"):
        uo.Obstacle.circle((0.0, 0.0), -1.0)
    with pytest.raises(ValueError, match="radius"):
        uo.Obstacle.moving(lambda t: (t, t), 0.0)
    with pytest.raises(ValueError, match="centre"):
        uo.Obstacle.circle((float("nan"), 0.0), 1.0)
    with pytest.raises(ValueError, match="centre"):
        uo.Obstacle.circle((0.0, float("inf")), 1.0)
    with pytest.raises(ValueError, match="centre"):
        uo.Obstacle.moving(lambda t: "ab", 1.0)  # a string, not (x, y) of t
    with pytest.raises(ValueError, match=r"centre path must return 2 values"):
        uo.Obstacle.moving(lambda t: (t, t, t), 1.0)  # wrong shape
    with pytest.raises(ValueError, match="centre"):
        uo.Obstacle.moving(lambda: (0.0, 0.0), 1.0)  # not a function of time
    with pytest.raises(ValueError, match="path must be a function of time"):
        uo.Obstacle.moving((1.0, 2.0), 1.0)
    with pytest.raises(ValueError, match="margin"):
        uo.Obstacle.circle((0.0, 0.0), 1.0, margin=-0.1)


# ------------------------------------------------------------------ the benchmark
def _bench_module():
    path = Path(__file__).resolve().parents[1] / "benchmarks" / "bench_nonconvex.py"
    spec = importlib.util.spec_from_file_location("bench_nonconvex", path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # dataclasses look their module up while it executes
    spec.loader.exec_module(module)
    return module


def test_benchmark_generator_builds_the_traps_it_claims():
    bench = _bench_module()
    fields = bench.instances(10, seed=5)
    assert [f.trap for f in fields] == [True, True, False, False, False] * 2
    for field in fields:
        goal = field.data["goal"]
        normal = np.array([-goal[1], goal[0]]) / np.hypot(*goal)
        discs = field.obstacles
        assert 3 <= len(discs) <= 8
        assert np.all(np.hypot(*discs[:, :2].T) > discs[:, 2])  # the start is free
        assert np.all(np.hypot(*(discs[:, :2] - goal).T) > discs[:, 2])  # the goal is free
        if field.trap:
            a, b = discs[0], discs[1]
            offset = float(a[:2] @ normal)  # signed distance of A's centre from the line
            assert 0.1 * a[2] - 1e-9 <= abs(offset) <= 0.3 * a[2] + 1e-9  # A straddles the line
            assert np.sign(b[:2] @ normal) == -np.sign(offset)  # B is on the line's side of A ...
            assert np.hypot(*(a[:2] - b[:2])) < a[2] + b[2]  # ... and overlaps it: no gap


@pytest.mark.slow
def test_benchmark_main_runs_at_a_tiny_size(capsys):
    bench = _bench_module()
    bench.main(["--instances", "4", "--workers", "1", "--reference-starts", "4"])
    out = capsys.readouterr().out
    assert "4 instances (2 traps, static obstacles" in out
    for label in bench.methods():
        assert f"\n{label} " in out
    assert "paired bootstrap 95% CI" in out


def test_benchmark_moving_fields_are_the_static_ones_where_the_vehicle_passes():
    bench = _bench_module()
    static, moving = bench.instances(10, seed=5), bench.instances(10, seed=5, moving=True)
    for still, field in zip(static, moving, strict=True):
        assert np.array_equal(still.data["goal"], field.data["goal"]) and np.array_equal(still.x0, field.x0)
        speeds = np.hypot(*field.velocities.T)
        assert np.all(speeds <= bench.MAX_SPEED) and np.any(speeds > 0.0)
        centres = field.data["centres"].reshape(bench.HORIZON + 1, bench.SLOTS, 2)[:, : len(field.obstacles)]
        times = bench.DT * np.arange(bench.HORIZON + 1)
        np.testing.assert_allclose(
            centres, field.obstacles[None, :, :2] + times[:, None, None] * field.velocities
        )
        goal = field.data["goal"]
        along = goal / np.hypot(*goal)
        passing = (
            np.clip(still.obstacles[:, :2] @ along / np.hypot(*goal), 0.0, 1.0) * bench.HORIZON * bench.DT
        )
        if field.trap:  # A and B move as one, placed where A straddles the line at A's passing time
            passing[1] = passing[0]
            assert np.array_equal(field.velocities[0], field.velocities[1])
        at_pass = field.obstacles[:, :2] + passing[:, None] * field.velocities
        np.testing.assert_allclose(at_pass, still.obstacles[:, :2], atol=1e-12)


def test_benchmark_wilson_interval_matches_the_textbook_and_the_quadratic():
    bench = _bench_module()
    # Newcombe (1998), Stat. Med. 17:857, example 81/263: Wilson 95 % interval 0.2553 to 0.3662
    low, high = bench.wilson(81, 263)
    assert (round(low, 4), round(high, 4)) == (0.2553, 0.3662)
    # second implementation: the roots in p of (p̂ − p)² = z² p (1 − p) / n
    for k, n in ((0, 10), (3, 10), (10, 10), (475, 500)):
        z2, share = bench.Z95**2, k / n
        roots = np.sort(np.roots([1 + z2 / n, -(2 * share + z2 / n), share**2]).real)
        assert bench.wilson(k, n) == pytest.approx(tuple(np.clip(roots, 0.0, 1.0)), abs=1e-12)
    with pytest.raises(ValueError, match="successes"):
        bench.wilson(11, 10)
    with pytest.raises(ValueError, match="trials"):
        bench.wilson(0, 0)


def test_benchmark_paired_bootstrap_is_seeded_and_near_the_normal_interval():
    bench = _bench_module()
    rng = np.random.default_rng(8)
    a = (rng.random(500) < 0.95).astype(float)
    b = np.where(rng.random(500) < 0.8, a, 1.0 - a)  # paired: b mostly agrees with a
    first, again = bench.paired_bootstrap(a, b, seed=3), bench.paired_bootstrap(a, b, seed=3)
    assert first == again and bench.paired_bootstrap(a, b, seed=4) != first
    mean, low, high = first
    difference = a - b
    assert mean == pytest.approx(difference.mean())
    half = bench.Z95 * difference.std(ddof=1) / np.sqrt(difference.size)  # the normal approximation
    assert low == pytest.approx(mean - half, abs=0.15 * half) and high == pytest.approx(
        mean + half, abs=0.15 * half
    )
    assert bench.paired_bootstrap(a, a) == (0.0, 0.0, 0.0)
    with pytest.raises(ValueError, match="equal-length"):
        bench.paired_bootstrap(a, b[:3])


def test_benchmark_resume_skips_done_instances_and_solves_a_corrupted_line_again(tmp_path, monkeypatch):
    bench = _bench_module()
    labels = list(bench.methods())
    solved = []

    class FakeRunner:  # stands for the solvers: records what it is asked to solve
        def __init__(self, config):
            self.config = config

        def solve(self, i):
            solved.append(i)
            return {
                "index": i,
                "cost": [1.0 + i] * len(labels),
                "ok": [True] * len(labels),
                "seconds": [0.01] * len(labels),
                "reference": 1.0 + i,
            }

    monkeypatch.setattr(bench, "Runner", FakeRunner)
    config = {
        "instances": 4,
        "seed": 1,
        "trap": 0.4,
        "moving": False,
        "reference_starts": 2,
        "methods": labels,
    }
    out = tmp_path / "rows.jsonl"
    good = FakeRunner(config)
    lines = [bench.encode_row(config, good.solve(i)) for i in range(3)]
    lines[1] = lines[1].replace('"cost": [2.0', '"cost": [0.5')  # a changed value: checksum fails
    other = bench.encode_row({**config, "seed": 2}, good.solve(2))  # another configuration
    out.write_text("\n".join([lines[0], lines[1], other, lines[2][:-9]]) + "\n")  # last line cut short
    solved.clear()
    rows, rejected = bench.read_rows(out, config)
    assert sorted(rows) == [0] and rejected == 3
    outcome = bench.run(config, out, progress=False)
    assert sorted(solved) == [1, 2, 3] and outcome["indices"] == [0, 1, 2, 3]
    assert outcome["cost"][:, 0].tolist() == [1.0, 2.0, 3.0, 4.0]  # not the corrupted 0.5
    solved.clear()
    again = bench.run(config, out, progress=False)
    assert solved == [] and again["indices"] == [0, 1, 2, 3]
