"""The documentation: tutorials run at reduced size and are checked; the site builds strictly.

Every tutorial script runs at reduced size and its results are checked independently, every
tutorial has a page that includes it, and ``mkdocs build --strict`` succeeds.
"""

from __future__ import annotations

import importlib.util
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from uuv_ocp.obstacles import closest_approach
from uuv_ocp.reference.path import WAYPOINT_HOLD

ROOT = Path(__file__).resolve().parents[2]
TUTORIALS = ROOT / "docs" / "tutorials"
TESTED = {
    "own_vehicle",
    "own_ocp",
    "surveys",
    "obstacles",
    "comparing_solvers",
    "closed_loop",
    "figures",
    "generated_c",
    "campaign",
}


def load(name):
    spec = importlib.util.spec_from_file_location(f"tutorial_{name}", TUTORIALS / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # dataclasses look their module up while the file runs
    spec.loader.exec_module(module)
    return module


def replay(dynamics, run, rtol=1e-10):
    """Integrate the plant's ODE under the run's controls (held per interval) with scipy's RK45."""
    states = [run.states[0]]
    for k, control in enumerate(run.controls):
        current = run.currents[k] if run.currents.shape[1] else []

        def rhs(_, x, control=control, current=current):
            return np.array(dynamics(x, control, current)).ravel()

        span = (run.t[k], run.t[k + 1])
        solution = solve_ivp(rhs, span, states[-1], rtol=rtol, atol=1e-12, method="DOP853")
        states.append(solution.y[:, -1])
    return np.array(states)


def test_every_tutorial_is_tested_and_has_a_page_including_it():
    scripts = {path.stem for path in TUTORIALS.glob("*.py")}
    assert scripts == TESTED
    mkdocs = (ROOT / "mkdocs.yml").read_text()
    for name in scripts:
        page = TUTORIALS / f"{name}.md"
        assert f'--8<-- "docs/tutorials/{name}.py"' in page.read_text(), name
        assert f"tutorials/{name}.md" in mkdocs, name


@pytest.mark.slow
def test_own_vehicle(capsys):
    module = load("own_vehicle")
    out = module.main(duration=8.0, horizon=10, settle=5.0)
    assert "survey-auv-3dof" in capsys.readouterr().out
    planar = module.PLANAR
    # top speed: X_u u + X_u|u| u² = F_u,max
    a, b, force = planar.quadratic_damping[0], planar.linear_damping[0], planar.max_thrust[0]
    assert out.top_speed == pytest.approx((-b + np.sqrt(b * b + 4 * a * force)) / (2 * a), rel=1e-9)
    # the closed loop is the plant's motion under the applied controls, which hold the box
    run = out.planar_run
    np.testing.assert_allclose(replay(planar.dynamics_function(), run), run.states, atol=1e-6)
    assert np.all(np.abs(run.controls) <= np.asarray(planar.max_thrust) + 1e-9)
    assert run.failures == 0 and out.planar_settled < 1e-4
    # 6-DOF: the vehicle is 1 % buoyant, so at rest without thrust it rises (z down) with
    # (W - B) / (m + Z_ẇ); under NMPC it follows the dive and stays level
    spatial = module.SPATIAL
    xdot = np.array(spatial.dynamics(np.zeros(12), np.zeros(6), np.zeros(3))).ravel()
    assert xdot[8] == pytest.approx((spatial.weight - spatial.buoyancy) / (30.0 + 25.0), rel=1e-9)
    run6 = out.spatial_run
    np.testing.assert_allclose(replay(spatial.dynamics, run6), run6.states, atol=1e-6)
    assert run6.failures == 0 and out.spatial_settled < 1e-3
    assert np.max(np.abs(run6.states[:, 3:5])) < 0.05  # roll and pitch regulated
    depth = run6.states[:, 2]
    assert depth[-1] > depth[0] + 0.05  # it did dive


def rk4(dynamics, x, u, dt):
    """One classical Runge-Kutta step of x' = f(x, u) (still water), written out here."""

    def f(state):
        return np.array(dynamics(state, u, [0.0, 0.0])).ravel()

    k1 = f(x)
    k2 = f(x + dt / 2 * k1)
    k3 = f(x + dt / 2 * k2)
    k4 = f(x + dt * k3)
    return x + dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4)


def check_parking_plan(module, plan, parameters, dt):
    """Check that the plan is the model's motion, clears the disc, holds the bounds, ends on the goal."""
    vehicle = module.VEHICLE
    dynamics = vehicle.dynamics_function()
    # to the accuracy the judge reports for this plan (sqp stops earlier than ipopt and fatrop)
    tol = max(1e-6, 10 * plan.max_violation)
    assert plan.max_violation < 1e-4
    # multiple shooting: each interval is one RK4 step of the model
    np.testing.assert_allclose(plan.states[0], np.zeros(6), atol=1e-12)
    for k, control in enumerate(plan.controls):
        np.testing.assert_allclose(plan.states[k + 1], rk4(dynamics, plan.states[k], control, dt), atol=tol)
    distance = np.linalg.norm(plan.states[1:, :2] - parameters["hazard"], axis=1)
    assert np.all(distance >= module.RADIUS - tol)
    np.testing.assert_allclose(plan.states[-1], [*parameters["goal"], 0.0, 0.0, 0.0], atol=tol)
    limit = np.asarray(vehicle.max_thrust)
    assert np.all(np.abs(plan.controls) <= limit + 1e-6)
    steps = np.diff(np.vstack([np.zeros(3), plan.controls]), axis=0)
    assert np.all(np.abs(steps) <= np.asarray(vehicle.max_thrust_rate) * dt * (1 + 1e-6))


@pytest.mark.slow
def test_own_ocp(capsys):
    module = load("own_ocp")
    out = module.main(horizon=20, dt=0.5, duration=4.0)
    printed = capsys.readouterr().out
    assert all(name in printed for name in ("ipopt", "fatrop", "sqp"))
    for name, plan in out.plans.items():
        assert plan.success, (name, plan.status)
        check_parking_plan(module, plan, out.parameters, dt=0.5)
    # a keep-out disc makes the problem non-convex: plans may pass it on different sides, but
    # each is a local optimum no worse than 10 % above the best one found
    costs = [plan.cost for plan in out.plans.values()]
    assert max(costs) <= 1.1 * min(costs)
    run = out.run
    assert run.failures == 0
    distance = np.linalg.norm(run.states[:, :2] - module.HAZARD, axis=1)
    assert distance.min() >= module.RADIUS - 1e-3  # the plant, between the plan's nodes
    assert np.linalg.norm(run.states[-1, :2] - module.GOAL[:2]) < np.linalg.norm(module.GOAL[:2])


@pytest.mark.slow
def test_surveys():
    module = load("surveys")
    width, spacing, lanes = 6.0, 2.0, 2
    out = module.main(
        width=width, spacing=spacing, lanes=lanes, duration=12.0, horizon=10, settle=6.0, out=None
    )
    radius = spacing / 2
    # the lawnmower: straight lanes shortened by the turns, joined by semicircles
    length = lanes * width - 2 * (lanes - 1) * radius + (lanes - 1) * np.pi * radius
    lawnmower = out.lawnmower
    # the survey, braking over its last turn radius b (2 b / v, b / v longer than at speed), then
    # the default hold at the last waypoint (docs/references.md)
    hold = WAYPOINT_HOLD
    assert lawnmower.t_end - lawnmower.t_start == pytest.approx(
        (length + radius) / module.SPEED + hold, rel=1e-9
    )
    cruise_end = lawnmower.t_end - hold - 2 * radius / module.SPEED
    samples = lawnmower.evaluate(np.linspace(lawnmower.t_start, cruise_end - 1e-6, 400))
    np.testing.assert_allclose(samples[:, 3], module.SPEED, rtol=1e-6)  # u_R: constant speed
    assert samples[:, 1].max() == pytest.approx((lanes - 1) * spacing, abs=1e-6)
    assert set(np.round(np.abs(samples[:, 5]), 6)) <= {0.0, round(module.SPEED / radius, 6)}
    side = width / 2
    square = out.square
    corner_radius = side / 5
    length = 3 * side + (side - 0.5) - 6 * corner_radius + 3 * (np.pi / 2) * corner_radius
    assert square.t_end - square.t_start == pytest.approx(
        (length + corner_radius) / module.SPEED + hold, rel=1e-9
    )
    for name, run in out.runs.items():
        assert run.failures == 0, name
        assert out.settled[name] < 0.05, name  # curvature steps at the joints: mm to cm errors


@pytest.mark.slow
def test_obstacles(tmp_path):
    module = load("obstacles")
    out = module.main(duration=14.0, horizon=15, dt=0.2, out=tmp_path / "obstacles.svg")
    with_zones, blind = out.runs.values()
    # recomputed here: the distance of the plant at every integration step to each enlarged zone
    assert with_zones.substep_states.shape[0] == 10 * with_zones.controls.shape[0] + 1
    surfaces = []
    for obstacle in module.OBSTACLES:
        centres = obstacle.centre_at(with_zones.substep_t)
        gap = np.linalg.norm(with_zones.substep_states[:, :2] - centres, axis=1)
        assert np.all(gap >= obstacle.radius + obstacle.margin - 1e-3), obstacle.name
        surfaces.append(np.min(gap) - obstacle.radius)
    # the library's distance to the zones themselves (no margin) is the one computed here
    assert closest_approach(module.OBSTACLES, with_zones, margin=False) == pytest.approx(
        min(surfaces), abs=1e-12
    )
    assert out.clearance[next(iter(out.runs))] >= -1e-3
    assert out.clearance[list(out.runs)[1]] < -0.5  # without them the line runs through the rock
    assert with_zones.failures == 0 and blind.failures == 0
    assert "keep-out zone" in (tmp_path / "obstacles.svg").read_text()


@pytest.mark.slow
def test_comparing_solvers(capsys):
    module = load("comparing_solvers")
    solvers = ("ipopt", "sqp", "igwo", "igwo+sqp")
    rows = module.main(solvers=solvers, horizon=15, swarm_budget=(8, 5), out=None)
    printed = capsys.readouterr().out
    assert "hybrid:" in printed and "igwo+ipopt" in printed
    by_name = {row.solver: row for row in rows}
    best = by_name["ipopt"].cost
    for name in ("sqp", "igwo+sqp"):  # interior point, SQP and swarm + SQP reach one optimum
        assert by_name[name].cost == pytest.approx(best, rel=1e-5), name
        assert by_name[name].feasible
    swarm = by_name["igwo"]
    assert swarm.evaluations == 8 * 6 and swarm.cost > best  # 48 evaluations: far from optimal
    assert swarm.rank == len(rows)  # ranked after the feasible plans
    assert sorted(row.rank for row in rows) == list(range(1, len(rows) + 1))


@pytest.mark.slow
def test_closed_loop():
    module = load("closed_loop")
    runs = module.main(duration=12.0, horizon=20, settle=8.0, out=None)
    settled = {label: np.max(np.linalg.norm(run.errors[run.t >= 8.0], axis=1)) for label, run in runs.items()}
    assert all(run.failures == 0 for run in runs.values())
    # what the controller does not know costs accuracy: the oracles track to sub-0.1 mm, the
    # naive controller keeps the current's offset
    assert settled["still water (oracle)"] < 1e-4
    assert settled["current known (oracle)"] < 1e-4
    assert settled["current unknown, ignored"] > 10 * settled["current known (oracle)"]
    # the realistic loop: the controller follows the EKF's estimate, whose error (a 0.5 m fix at
    # 1 Hz) is what remains: far above the oracle's, below the fix's own 0.5 m
    for label in ("current unknown, EKF", "mismatch, EKF"):
        run = runs[label]
        assert 10 * settled["current known (oracle)"] < settled[label] < 0.5, label
        assert run.estimates is not None and run.measurements.sensors[0] == "position"
    realistic = runs["current unknown, EKF"]
    n = len(realistic.estimates.t)
    # the estimated current converged to the plant's (the EKF on the exact model)
    assert np.linalg.norm(realistic.estimates.currents[-1] - realistic.currents[n - 1]) < 0.1
    # the plant felt the tutorial's current: its Gauss-Markov path from the run's seed (7)
    expected = module.CURRENT.sample(realistic.controls.shape[0], 0.1, np.random.default_rng(7))
    for label in ("current known (oracle)", "current unknown, EKF"):
        np.testing.assert_allclose(runs[label].currents, expected, rtol=1e-12)
    assert np.all(runs["still water (oracle)"].currents == 0)
    # the mismatch run's plant is the exact RexROV: replaying its controls reproduces it
    import uuv_ocp as uo

    mismatch = runs["mismatch, EKF"]
    replayed = replay(uo.Vehicle.rexrov().dynamics_function(), mismatch, rtol=1e-9)
    np.testing.assert_allclose(replayed, mismatch.states, atol=1e-5)


@pytest.mark.slow
def test_campaign(tmp_path, capsys):
    import uuv_ocp as uo

    module = load("campaign")
    out = module.main(trials=2, more=3, duration=2.0, horizon=8, workers=1, out=tmp_path)
    first, second, rows = out["first"], out["second"], out["rows"]
    assert second.resumed == 2 and second.directory == first.directory
    np.testing.assert_equal(second.trials[:2], first.trials)  # NaN-aware: nothing is settled in 2 s
    assert [row["trial"] for row in rows] == [0, 1, 2] and "3 trials: 2 read back" in capsys.readouterr().out
    exact, path = uo.Vehicle.rexrov(), uo.Reference.paper("s2")
    for row in rows:
        run = uo.ClosedLoopResult.load(str(tmp_path / row["path"]))
        # the metrics in the index are those of the recorded arrays, against the path itself
        np.testing.assert_allclose(run.reference, path.evaluate(run.t), rtol=0, atol=1e-12)
        assert row["max_abs_ex"] == pytest.approx(
            np.max(np.abs(run.states[:, 0] - path.evaluate(run.t)[:, 0]))
        )
        # the plant was the exact RexROV under the recorded current: scipy replays it
        np.testing.assert_allclose(replay(exact.dynamics_function(), run, rtol=1e-9), run.states, atol=1e-5)
        assert np.all(np.hypot(*run.currents.T) > 0)
    assert second.summary["mean_max_abs_ey"] == pytest.approx(np.mean([r["max_abs_ey"] for r in rows]))
    # on Dask: the same trials, recorded in their own folder, with the same arrays
    on_dask = out["dask"]
    assert on_dask.directory.parent == tmp_path / "dask"
    for row in rows:
        local = uo.ClosedLoopResult.load(str(tmp_path / row["path"]))
        remote = uo.ClosedLoopResult.load(str(on_dask.directory / Path(row["path"]).name))
        np.testing.assert_array_equal(remote.states, local.states)
        np.testing.assert_array_equal(remote.controls, local.controls)


@pytest.mark.slow
def test_figures(tmp_path):
    module = load("figures")
    written = module.main(duration=2.0, horizon=10, out=tmp_path)
    for name in ("xoy", "errors", "thrust", "states"):
        svg = written[f"{name}.svg"].read_text()
        assert "still water" in svg and "current unknown" in svg, name  # the user's labels
        assert written[f"{name}.png"].read_bytes().startswith(b"\x89PNG")
    assert "|e_x| (m)" in written["errors.svg"].read_text()
    assert written["errors_xy.pdf"].read_bytes().startswith(b"%PDF")
    if importlib.util.find_spec("PIL") is not None:
        assert written["loop.gif"].read_bytes().startswith(b"GIF8")


@pytest.mark.slow
def test_generated_c(tmp_path, monkeypatch):
    from uuv_ocp.native.compile import CompilerNotFoundError, find_c_compiler

    try:
        find_c_compiler()
    except CompilerNotFoundError:
        pytest.skip("no C compiler")
    monkeypatch.setenv("UUV_OCP_CACHE", str(tmp_path / "cache"))
    out = load("generated_c").main(horizon=8, population=8, directory=tmp_path / "c")
    code, plan = out["code"], out["plan"]
    assert code.library.exists() and code.header.exists()
    assert max(code.max_error.values()) <= 1e-12
    np.testing.assert_allclose(out["states"], plan.states, atol=1e-9)
    assert out["objective"] == pytest.approx(plan.cost, rel=1e-9)


@pytest.mark.slow
def test_site_builds_strict(tmp_path):
    if importlib.util.find_spec("mkdocs") is None:
        pytest.skip("mkdocs not installed (make docs installs it)")
    result = subprocess.run(
        [sys.executable, "-m", "mkdocs", "build", "--strict", "-d", str(tmp_path / "site")],
        cwd=ROOT,
        env={**os.environ, "NO_MKDOCS_2_WARNING": "1"},
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert result.returncode == 0, result.stderr[-4000:]
    warnings = [line for line in result.stderr.splitlines() if re.match(r"^WARNING", line)]
    assert warnings == []
    assert (tmp_path / "site" / "api" / "problems.html").exists()
    assert broken_local_links(tmp_path / "site") == []


def broken_local_links(site: Path) -> list[str]:
    """Links of the built pages that do not open a file when the site is read from disk.

    Under ``file://`` a link to a folder (``cli/``) opens a directory listing, not the page, so
    every relative ``href`` and ``src`` must name an existing file (``use_directory_urls: false``).
    """
    broken = []
    for page in sorted(set(site.rglob("*.html")) - {site / "404.html"}):  # 404: served, never opened
        for link in re.findall(r'(?:href|src)="([^"]*)"', page.read_text(encoding="utf-8")):
            target = link.split("#", 1)[0].split("?", 1)[0]
            if not target or re.match(r"^[a-z][a-z0-9+.-]*:|^//", target):
                continue  # an anchor on the page, or another site
            resolved = (page.parent / target).resolve()
            if not resolved.is_file():
                broken.append(f"{page.relative_to(site)}: {link}")
    return broken
