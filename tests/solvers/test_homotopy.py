"""Initial guesses across homotopy classes (uuv_ocp.solvers.homotopy) and the hybrids' class starts."""

import time

import casadi as ca
import numpy as np
import pytest

import uuv_ocp as uo
from uuv_ocp.solvers import homotopy
from uuv_ocp.solvers.homotopy import Geometry
from uuv_ocp.solvers.nlp import NlpSolver
from uuv_ocp.solvers.result import Iterate

N, DT = 20, 0.375
GOAL = np.array([10.0, 0.0])
# one disc straddling the line, its centre 0.1 m to the left: a solver started on the line is
# pushed to the right, while the vehicle starts moving left at 1 m/s, so left is the better class
TRAP = np.array([[5.0, 0.1, 1.5]])
LATERAL = 1.0


def _cross(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    return u[..., 0] * v[..., 1] - u[..., 1] * v[..., 0]


def _field(discs: np.ndarray, lateral: float = 0.0) -> tuple[uo.Ocp, np.ndarray, Iterate, Geometry]:
    """Planar double integrator from the origin to GOAL tracking the straight line among ``discs``.

    It starts at the line's speed plus ``lateral`` m/s to its left.
    """
    ocp = uo.Ocp(horizon=N, dt=DT, name="homotopy_test")
    pos, vel = ocp.state("pos", 2), ocp.state("vel", 2)
    acc = ocp.control("acc", 2, lower=-1.0, upper=1.0, max_rate=2.0)
    line = ocp.parameter("line", 2, stagewise=True)
    ocp.set_der(pos, vel)
    ocp.set_der(vel, acc)
    ocp.add_stage_cost(residual=ca.vertcat(0.3 * (pos - line), 0.5 * acc), start=1)
    ocp.add_terminal_cost(residual=ca.vertcat(3.0 * (pos - ca.DM(GOAL)), vel))
    for x, y, r in discs:
        ocp.subject_to(ca.sumsqr(pos - ca.DM([x, y])) >= r**2)
    speed = GOAL / (N * DT)
    path = np.linspace(0.0, 1.0, N + 1)[:, None] * GOAL
    x0 = np.r_[0.0, 0.0, speed + [0.0, lateral]]
    p = ocp.parameters(x0, {"line": path})
    states = np.column_stack([path, np.tile(speed, (N + 1, 1))])
    states[0] = x0
    guess = Iterate(scaled_controls=np.zeros((N, 2)), states=states)
    geometry = Geometry(np.tile(discs, (N + 1, 1, 1)), (0, 1), (2, 3), DT)
    return ocp, p, guess, geometry


def test_class_paths_pass_each_blocker_on_the_stated_side():
    rng = np.random.default_rng(4)
    path = np.linspace(0.0, 1.0, N + 1)[:, None] * GOAL
    checked = 0
    for _ in range(20):
        discs = np.column_stack(
            [rng.uniform(2.0, 8.0, 3), rng.uniform(-0.8, 0.8, 3), rng.uniform(0.5, 1.2, 3)]
        )
        discs[:, 0] = np.sort(discs[:, 0]) + np.array([0.0, 0.5, 1.0])  # apart along the line
        track = np.tile(discs, (N + 1, 1, 1))
        classes = homotopy.class_paths(path, track)
        found = [i for i, _ in homotopy.blockers(path, track)]
        assert len(classes) <= 2 ** len(found)
        for sides, pushed in classes:
            assert np.allclose(pushed[0], path[0])  # the measured state stays
            for i, side in sides.items():
                centre = discs[i, :2]
                nearest = pushed[np.argmin(np.abs(pushed[:, 0] - centre[0]))]
                # independent check: sign of (chord) × (node − centre) at the node abreast of it
                assert np.sign(_cross(GOAL - path[0], nearest - centre)) == side
                checked += 1
    assert checked > 40


def test_a_single_push_clears_the_disc_and_moves_only_nearby_nodes():
    path = np.linspace(0.0, 1.0, N + 1)[:, None] * GOAL
    track = np.tile([5.0, 0.2, 1.0], (N + 1, 1))
    for side in (1.0, -1.0):
        pushed = homotopy.push(path, track, side)
        distance = np.hypot(*(pushed - track[:, :2]).T)
        assert np.all(distance >= 1.0 - 1e-12)
        far = np.abs(path[:, 0] - 5.0) >= 1.1
        assert np.array_equal(pushed[far], path[far])


def test_blockers_are_the_discs_the_path_enters_deepest_first():
    path = np.linspace(0.0, 1.0, N + 1)[:, None] * GOAL
    discs = np.array([[3.0, 0.5, 1.0], [6.0, -0.1, 1.0], [8.0, 3.0, 1.0]])
    found = homotopy.blockers(path, np.tile(discs, (N + 1, 1, 1)))
    assert [i for i, _ in found] == [1, 0]  # the third is 2 m clear of the line
    assert [d for _, d in found] == pytest.approx([0.9, 0.5])


def test_blockers_see_a_disc_between_two_nodes():
    path = np.array([[0.0, 0.0], [4.0, 0.0], [8.0, 0.0]])
    disc = np.array([[[2.0, 0.5, 0.7]]] * 3)  # both nodes 2.06 m away, the segment 0.5 m
    assert homotopy.blockers(path, disc) == [(0, pytest.approx(0.2))]


def test_class_start_reaches_the_better_class_where_the_straight_start_does_not():
    ocp, p, guess, geometry = _field(TRAP, LATERAL)
    fatrop = uo.get_solver(ocp, "fatrop")
    straight = fatrop.solve(p, guess)
    # independent references: fatrop from hand-made paths bowing well above and below the disc
    refs = {}
    for side, offset in (("above", 2.2), ("below", -2.2)):
        states = guess.states.copy()
        bump = np.sin(np.linspace(0.0, np.pi, N + 1)) ** 0.5
        states[:, 1] = offset * bump
        refs[side] = fatrop.solve(p, Iterate(scaled_controls=np.zeros((N, 2)), states=states))
    assert refs["above"].success and refs["below"].success
    assert refs["above"].cost < 0.8 * refs["below"].cost  # the class above is clearly better
    assert straight.cost == pytest.approx(refs["below"].cost, rel=1e-5)  # the straight start misses it
    starts = [fatrop.solve(p, g) for _, g in homotopy.class_guesses(ocp, p, guess, geometry)]
    best = min(r.cost for r in starts if r.success)
    assert best == pytest.approx(refs["above"].cost, rel=1e-5)


def test_the_default_hybrid_starts_the_exact_solver_from_the_classes_too():
    ocp, p, guess, geometry = _field(TRAP, LATERAL)
    every = {"geometry": lambda _: geometry, "skip_swarm_class": False}
    hybrid = uo.get_solver(ocp, "pso+fatrop", every)
    result = hybrid.solve(p, guess, np.random.default_rng(3))
    starts = [c["start"] for c in result.details["candidates"]]
    assert starts == ["swarm 0", "class 0R", "class 0L"]  # one blocker: both of its classes
    assert result.details["class_starts"] == 2
    kept = uo.get_solver(ocp, "pso+fatrop", {**every, "candidates": 2})
    starts = [c["start"] for c in kept.solve(p, guess, np.random.default_rng(3)).details["candidates"]]
    assert starts == ["swarm 0", "warm start", "class 0R", "class 0L"]
    assert result.cost == pytest.approx(min(c["cost"] for c in result.details["candidates"] if c["success"]))
    again = hybrid.solve(p, guess, np.random.default_rng(3))  # seeded: the same result
    assert again.cost == result.cost and again.details["chosen"] == result.details["chosen"]
    off = uo.get_solver(ocp, "pso+fatrop", {"geometry": lambda _: geometry, "classes": 0})
    assert "candidates" not in off.solve(p, guess, np.random.default_rng(3)).details


def test_a_tracking_problem_gives_its_obstacles_fixed_and_moving():
    reference = uo.Reference.from_xy(lambda t: 0.5 * t, lambda t: 0 * t, name="line", t_end=30.0)
    crossing = uo.Obstacle.moving(lambda t: (3.0 + 0 * t, -2.1 + 0.3 * t), 0.3, margin=0.1)
    fixed = uo.Obstacle.ellipse((2.8, 1.0), (0.4, 0.2), margin=0.1)
    problem = uo.TrackingProblem(uo.Vehicle.rexrov(), reference, terminal="cost", obstacles=[crossing, fixed])
    t0 = 4.5
    p = problem.parameters(reference.evaluate([t0])[0], t0)
    geometry = homotopy.geometry_of(problem, p)
    times = t0 + problem.dt * np.arange(problem.horizon + 1)
    # the centres in numpy from the paths above; an ellipse is its larger half-axis' circle
    np.testing.assert_allclose(
        geometry.discs[:, 0, :2], np.column_stack([3.0 + 0 * times, -2.1 + 0.3 * times])
    )
    np.testing.assert_allclose(geometry.discs[:, 0, 2], 0.4)
    np.testing.assert_allclose(geometry.discs[:, 1], np.tile([2.8, 1.0, 0.5], (times.size, 1)))
    assert geometry.position == (0, 1)
    assert homotopy.geometry_of(problem.replace(obstacles=()), p) is None


@pytest.mark.parametrize(
    ("options", "match"),
    [
        ({"classes": -1}, r"options\['classes'\].*integer >= 0"),
        ({"classes": 1.5}, r"options\['classes'\].*integer >= 0"),
        ({"classes": True}, r"options\['classes'\].*integer >= 0"),
        ({"geometry": "discs"}, r"options\['geometry'\].*callable"),
    ],
)
def test_bad_class_options_are_refused_by_name(options, match):
    ocp, _, _, _ = _field(TRAP[:1])
    with pytest.raises(ValueError, match=match):
        uo.get_solver(ocp, "pso+fatrop", options)


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"discs": np.zeros((3, 2))}, "discs must have shape"),
        ({"discs": np.zeros((3, 1, 3))}, "radii > 0"),
        ({"position": (0,)}, "position must be 2 state columns"),
        ({"velocity": (2, -1)}, "velocity must be 2 state columns"),
        ({"dt": 0.0}, "dt must be a finite number > 0"),
        ({"dt": "x"}, "dt must be a real number"),
        ({"position": 3}, "position must be 2 state columns"),
    ],
)
def test_bad_geometry_is_refused_by_name(kwargs, match):
    fields = {"discs": np.ones((3, 1, 3)), "position": (0, 1), "velocity": None, "dt": 1.0}
    with pytest.raises(ValueError, match=match):
        Geometry(**{**fields, **kwargs})


def test_a_geometry_provider_of_the_wrong_horizon_is_refused_by_name():
    ocp, p, _, geometry = _field(TRAP[:1])
    short = Geometry(geometry.discs[:1], geometry.position, geometry.velocity, geometry.dt)
    with pytest.raises(ValueError, match="geometry's discs must have"):
        homotopy.geometry_of(ocp, p, lambda _: short)
    with pytest.raises(ValueError, match="geometry must return a homotopy.Geometry"):
        homotopy.geometry_of(ocp, p, lambda _: "discs")
    assert homotopy.geometry_of(ocp, p, lambda _: geometry) is geometry


def _side(path: np.ndarray, centre: np.ndarray) -> int:
    """Independent side of ``centre``: the chord × (node − centre) at the node abreast of it (x)."""
    k = 1 + int(np.argmin(np.abs(path[1:, 0] - centre[0])))
    return int(np.sign(_cross(path[-1] - path[0], path[k] - centre)))


def test_sides_name_the_side_of_every_disc_and_the_skip_drops_the_solved_class():
    ocp, p, guess, geometry = _field(np.array([[3.5, 0.2, 1.0], [7.0, -0.3, 1.0]]), 0.5)
    centres = geometry.discs[0, :, :2]
    classes = homotopy.class_guesses(ocp, p, guess, geometry)
    assert len(classes) == 4
    for label, start in classes:
        expected = tuple(_side(start.states[:, :2], c) for c in centres)
        assert homotopy.sides(start.states[:, :2], geometry.discs) == expected
        assert all(f"{i}{'L' if s > 0 else 'R'}" in label for i, s in enumerate(expected))
    skip = uo.get_solver(ocp, "pso+fatrop", {"geometry": lambda _: geometry})
    full = uo.get_solver(ocp, "pso+fatrop", {"geometry": lambda _: geometry, "skip_swarm_class": False})
    # the exact solve from the swarm's plan (same seed, same plan), its sides found independently
    fatrop = uo.get_solver(ocp, "fatrop")
    skipped_any = False
    for seed in range(4):
        result = skip.solve(p, guess, np.random.default_rng(seed))
        everything = full.solve(p, guess, np.random.default_rng(seed))
        plan = skip.first.solve(p, guess, np.random.default_rng(seed)).iterate
        solved = fatrop.solve(p, plan)
        sides = tuple(_side(solved.states[:, :2], c) for c in centres)
        same = [
            label for label, g in classes[1:] if tuple(_side(g.states[:, :2], c) for c in centres) == sides
        ]
        assert result.details.get("skipped_starts", []) == same  # never the nearest class
        ran = [c["start"] for c in result.details["candidates"]]
        assert ran == ["swarm 0"] + [label for label, _ in classes if label not in same]
        skipped_any |= bool(same)
        # the skipped starts found nothing better: both hybrids return the same plan
        assert result.cost == pytest.approx(everything.cost, rel=1e-9)
    assert skipped_any


def test_shared_cold_retries_run_once_and_change_no_result(monkeypatch):
    # three discs where some class starts fail at first and retry from the cold guess
    discs = np.array([[7.643, 0.429, 0.805], [6.987, -0.56, 1.218], [2.515, 0.276, 1.025]])
    ocp, p, guess, geometry = _field(discs, 0.5)
    options = {"geometry": lambda _: geometry, "skip_swarm_class": False}
    shared = uo.get_solver(ocp, "pso+fatrop", options).solve(p, guess, np.random.default_rng(1))
    assert shared.details["cold_retries_reused"] >= 1
    # the same hybrid with every cold retry run again (sharing switched off)
    monkeypatch.setattr(NlpSolver, "share_cold_retries", lambda self, retries: None)
    alone = uo.new_solver(ocp, "pso+fatrop", options).solve(p, guess, np.random.default_rng(1))
    assert "cold_retries_reused" not in alone.details
    np.testing.assert_array_equal(shared.states, alone.states)
    for a, b in zip(shared.details["candidates"], alone.details["candidates"], strict=True):
        assert (a["start"], a["cost"], a["status"], a["iterations"]) == (
            b["start"],
            b["cost"],
            b["status"],
            b["iterations"],
        )


# two discs on the line, apart along it: four classes (left/right of each), each reachable
PAIR = np.array([[3.5, 0.2, 1.0], [7.0, -0.3, 1.0]])


def test_a_path_fit_recovers_a_reachable_path():
    ocp, p, _, geometry = _field(PAIR)
    fit = homotopy.PathFit(ocp, geometry.position)
    rng = np.random.default_rng(7)
    decode = ocp.build().decode
    for _ in range(3):
        # the path of a known interior W (its rollout in numpy: the double integrator exactly)
        truth = rng.uniform(-0.6, 0.6, 2 * N)
        acc = np.asarray(decode(truth, p)).reshape(N, 2)
        pos, vel = np.zeros((N + 1, 2)), np.zeros((N + 1, 2))
        vel[0] = p[ocp.spec().layout.x0][2:]
        for k in range(N):
            pos[k + 1] = pos[k] + DT * vel[k] + 0.5 * DT**2 * acc[k]
            vel[k + 1] = vel[k] + DT * acc[k]
        w = fit(pos, np.zeros(2 * N), p)
        assert np.all(np.abs(w) <= 1.0)
        # within 5 mm: the last controls hardly move the path, so the fit converges slowly there
        np.testing.assert_allclose(fit.positions(w, p), pos, atol=5e-3)


def _captured_population(monkeypatch, hybrid, p, guess, seed):
    """Run ``hybrid`` and return its swarm's initial individuals (absolute W) and the result."""
    from uuv_ocp.solvers import swarm as swarm_module

    seen = {}
    original = swarm_module.minimize

    def spy(objective, lower, upper, *args, **kwargs):
        seeds = kwargs["initial_population"]
        # lower = -1 - offset: the rows back in absolute coordinates
        seen["rows"] = None if seeds is None else seeds + (-1.0 - lower)
        return original(objective, lower, upper, *args, **kwargs)

    monkeypatch.setattr(swarm_module, "minimize", spy)
    result = hybrid.solve(p, guess, np.random.default_rng(seed))
    return seen["rows"], result


def test_the_classes_population_seeds_every_class_inside_the_bounds(monkeypatch):
    ocp, p, guess, geometry = _field(PAIR, 0.5)
    options = {"geometry": lambda _: geometry, "initial_population": "classes"}
    hybrid = uo.get_solver(ocp, "pso+fatrop", options)
    rows, result = _captured_population(monkeypatch, hybrid, p, guess, 3)
    population = hybrid.first.population
    assert rows.shape == (1 + population // 2, 2 * N)  # the centre plan, then the class share
    assert result.details["class_particles"] == population // 2
    decode = ocp.build().decode
    spec = ocp.spec()
    wanted = {
        tuple(_side(path, c) for c in PAIR[:, :2])
        for _, path in homotopy.class_paths(guess.states[:, :2], geometry.discs)
    }
    assert len(wanted) == 4
    found = set()
    previous = spec.physical(ocp.previous_scaled(p))
    for w in rows[1:]:
        acc = spec.physical(np.asarray(decode(w, p)).reshape(N, 2))
        # the bounds, checked on the physical controls: the box and the rate (2 m/s³ × dt)
        assert np.all(np.abs(acc) <= 1.0 + 1e-12)
        steps = np.diff(np.vstack([previous, acc]), axis=0)
        assert np.all(np.abs(steps) <= 2.0 * DT + 1e-9)
        states = ocp.rollout(acc, p)
        found.add(tuple(_side(states[:, :2], c) for c in PAIR[:, :2]))  # independent sides
    assert found == wanted
    again, repeat = _captured_population(monkeypatch, hybrid, p, guess, 3)  # seeded
    np.testing.assert_array_equal(again, rows)
    assert repeat.cost == result.cost


def test_the_uniform_population_is_the_swarms_own(monkeypatch):
    ocp, p, guess, geometry = _field(PAIR, 0.5)
    default = uo.get_solver(ocp, "pso+fatrop", {"geometry": lambda _: geometry})
    uniform = uo.new_solver(
        ocp, "pso+fatrop", {"geometry": lambda _: geometry, "initial_population": "uniform"}
    )
    rows, result = _captured_population(monkeypatch, uniform, p, guess, 5)
    assert rows.shape[0] == 1  # only the centre plan, as without the option
    before = default.solve(p, guess, np.random.default_rng(5))
    np.testing.assert_array_equal(result.states, before.states)
    assert result.cost == before.cost and "class_particles" not in result.details


@pytest.mark.parametrize(
    ("name", "options", "match"),
    [
        ("pso+fatrop", {"initial_population": "lines"}, r"options\['initial_population'\]"),
        ("pso+fatrop", {"class_share": 1.0}, r"options\['class_share'\].*\(0, 1\)"),
        ("pso+fatrop", {"class_share": 0.0}, r"options\['class_share'\]"),
        ("mppi+fatrop", {"initial_population": "classes"}, "takes_initial"),
    ],
)
def test_bad_population_options_are_refused_by_name(name, options, match):
    ocp, _, _, _ = _field(TRAP[:1])
    with pytest.raises(ValueError, match=match):
        uo.get_solver(ocp, name, options)


def test_without_a_class_path_the_seeding_builds_no_path_fit(monkeypatch):
    """Building a PathFit costs 0.4 s (RexROV, N = 20): only when some class path exists."""
    far = np.array([[5.0, 8.0, 1.0]])  # off the path: nothing in the way
    ocp, p, guess, geometry = _field(far, 0.5)
    options = {"geometry": lambda _: geometry, "initial_population": "classes"}
    hybrid = uo.new_solver(ocp, "pso+fatrop", options)
    built = []

    class CountedFit(homotopy.PathFit):
        def __init__(self, *args):
            built.append(1)
            super().__init__(*args)

    monkeypatch.setattr(homotopy, "PathFit", CountedFit)
    result = hybrid.solve(p, guess, np.random.default_rng(0))
    assert built == [] and hybrid._fit is None and "class_particles" not in result.details
    assert result.details["seeding_time"] >= 0.0
    ocp, p, guess, geometry = _field(PAIR, 0.5)  # two discs in the way: the fit is built, once
    hybrid = uo.new_solver(
        ocp, "pso+fatrop", {"geometry": lambda _: geometry, "initial_population": "classes"}
    )
    hybrid.solve(p, guess, np.random.default_rng(0))
    hybrid.solve(p, guess, np.random.default_rng(1))
    assert built == [1] and hybrid._fit is not None


@pytest.mark.parametrize("seeding", [0.3, 0.5])
def test_the_class_seeding_counts_against_the_deadline(monkeypatch, seeding):
    """The swarm gets min(SWARM_SHARE deadline, what the seeding left).

    It was handed its full share after the seeding, so seeding + swarm could use the whole
    deadline (or more) and blame the swarm.

    A seeding made to last at least ``seeding`` s (a sleep) against a 0.4 s deadline: the
    swarm's time limit is checked, not how long anything took.
    """
    from uuv_ocp.solvers import hybrid as hybrid_module

    ocp, p, guess, geometry = _field(PAIR, 0.5)
    deadline = 0.4
    options = {"geometry": lambda _: geometry, "initial_population": "classes", "deadline": deadline}
    hybrid = uo.new_solver(ocp, "pso+fatrop", options)
    original_seeds = homotopy.class_seeds

    def slow_seeds(*args, **kwargs):
        time.sleep(seeding)
        return original_seeds(*args, **kwargs)

    limits = []
    original_solve = hybrid.first.solve

    def spy(*args, time_limit=None, **kwargs):
        limits.append(time_limit)
        return original_solve(*args, time_limit=time_limit, **kwargs)

    monkeypatch.setattr(homotopy, "class_seeds", slow_seeds)
    monkeypatch.setattr(hybrid.first, "solve", spy)
    result = hybrid.solve(p, guess, np.random.default_rng(0))
    seeding_time = result.details["seeding_time"]
    assert seeding_time >= seeding
    (limit,) = limits
    assert limit <= max(deadline - seeding, hybrid_module.MIN_SWARM_TIME)
    assert limit <= hybrid_module.SWARM_SHARE * deadline
    if seeding > deadline:  # nothing left for the exact stage: the swarm's plan, marked late
        assert limit == hybrid_module.MIN_SWARM_TIME and result.details["deadline_hit"]
        assert "class seeding" in result.status
