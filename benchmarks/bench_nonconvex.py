"""Where the metaheuristic warm start earns its place: seeded obstacle fields, several homotopy classes.

Problem (one :class:`uuv_ocp.Ocp`, built and compiled once; every instance is parameter data):
a planar double integrator ``p̈ = a`` (a point vehicle of 0.2 m radius, included in the
obstacle radii), ``N = 20`` intervals of ``dt = 0.375`` s (7.5 s), acceleration box
``|a_i| ≤ 1`` m/s² and rate bound ``|ȧ_i| ≤ 2`` m/s³, stage cost
``Σ_{k≥1} 0.3²‖p_k − r_k‖² + 0.5²‖a_k‖²`` against the straight line ``r`` from start to goal
at constant speed, terminal cost ``3²‖p_N − goal‖² + ‖v_N‖²``, and up to 8 circular obstacles
``‖p_k − c_i‖² ≥ ρ_i²`` on nodes 1..N (centres and radii are parameters; unused slots sit far
away).  Chosen over the RexROV tracking preset (and over N = 30, which doubled the exact
solvers' time) because the whole benchmark — 200 instances × 11 methods + a 32-start
reference, ~3.6 s of CPU per instance — fits in ~7 minutes on two otherwise idle cores, while
keeping what matters here: a smooth NLP whose obstacle constraints make it non-convex, with
one local optimum per homotopy class.

Instances (:func:`instances`, seeded): start at the origin moving along the line at its speed
plus a lateral velocity ``U(−0.3, 0.3)`` m/s, goal at ``(U(8, 11), U(−1, 1))`` m, 3–8
obstacles of radius 0.4–1.0 m (+ margin) placed near the line.  A fixed share (``--trap``,
default 40 %) are *traps*: an obstacle A (radius 0.8–1.3 m) straddles the line, its centre
0.1–0.3 radii off it, and a blocker B (0.7–1.1 m) overlaps A on the side of the line, so the
straight line lies on the side where the path must go around both — the worse homotopy class —
while a gradient solver started on the line is pushed to it (away from A's centre).

Methods: fatrop, ipopt, sqp from the straight-line guess (states on the line, zero
acceleration); multistart-ipopt (8 starts: the straight line first, see
:mod:`uuv_ocp.solvers.multistart`); multistart-fatrop with as many starts as the candidate
hybrid solves (about equal time); igwo and pso (the paper's budgets, compiled where a C
compiler exists); igwo+fatrop and pso+fatrop (one candidate); pso+fatrop with
``candidates=2`` (the exact solver from the swarm's best plan and from the straight line, the
hybrid's ``keep_warm_start`` default); both swarms with ``candidates=4`` (the swarm's best
plan, the straight line, then the swarm's next 2 distinct plans, default state-trajectory
distance); and pso+fatrop with ``candidates=4, keep_warm_start=False`` (the swarm's 4 plans
only: what the hybrid did before the warm start was kept).
Every method gets the same straight-line warm start and, for the random parts, the generator
``default_rng([seed, i])`` on instance ``i``.  The best-known cost of an instance is the best
feasible cost found by any of them or by a 32-start multistart-fatrop (its starts capped at
150 iterations: it only has to find the best class).

Columns: ``best-known`` = share of instances whose result is feasible (``success`` and
``max_violation ≤ 1e-6``) and within 1 % of the best-known cost (``trap`` / ``other``: the same
on the two kinds of instance); ``infeasible`` = share not feasible; median and p90 wall time of
``backend.solve`` per instance (builds and compilation excluded), and the median relative to
single fatrop's.  With ``--workers 2`` (default) the instances are split over two processes,
one solve per core at a time; on a machine busy with other work every time grows alike.

Run: ``python -m benchmarks.bench_nonconvex [--instances 200] [--seed 11] [--trap 0.4]
[--workers 2]`` (part of ``make bench``).
"""

from __future__ import annotations

import argparse
import time
from dataclasses import dataclass

import casadi as ca
import numpy as np

import uuv_ocp as uo
from uuv_ocp.solvers.result import Iterate, SolveResult

HORIZON, DT = 20, 0.375
SLOTS = 8  # obstacle slots of the Ocp
MARGIN = 0.2  # vehicle radius (m), added to every obstacle radius
WITHIN = 0.01  # "reaches the best-known cost": within 1 %
FEASIBLE = 1e-6  # largest violation of a feasible result
REFERENCE_STARTS = 32


def field_ocp() -> uo.Ocp:
    """Declare the planar double integrator among up to ``SLOTS`` circular obstacles (parameters)."""
    ocp = uo.Ocp(horizon=HORIZON, dt=DT, name="obstacle_field")
    pos = ocp.state("pos", 2)
    vel = ocp.state("vel", 2)
    acc = ocp.control("acc", 2, lower=-1.0, upper=1.0, max_rate=2.0)
    goal = ocp.parameter("goal", 2)
    line = ocp.parameter("line", 2, stagewise=True)
    centres = ocp.parameter("centres", 2 * SLOTS)
    radii = ocp.parameter("radii", SLOTS)
    ocp.set_der(pos, vel)
    ocp.set_der(vel, acc)
    ocp.add_stage_cost(residual=ca.vertcat(0.3 * (pos - line), 0.5 * acc), start=1)
    ocp.add_terminal_cost(residual=ca.vertcat(3.0 * (pos - goal), vel))
    for i in range(SLOTS):
        ocp.subject_to(ca.sumsqr(pos - centres[2 * i : 2 * i + 2]) >= radii[i] ** 2)
    return ocp


@dataclass(frozen=True)
class Instance:
    """One obstacle field: initial state, parameter data, straight-line guess, and its kind."""

    x0: np.ndarray
    data: dict
    guess: Iterate
    trap: bool
    obstacles: np.ndarray  # (n, 3): centre x, centre y, radius with margin


def _disc_gap(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.hypot(*(a[:2] - b[:2])) - a[2] - b[2])


def instances(count: int, seed: int = 11, trap_share: float = 0.4) -> list[Instance]:
    """``count`` seeded obstacle fields; the first ``round(trap_share * 5)`` of every 5 are traps."""
    rng = np.random.default_rng(seed)
    traps_per_five = round(5 * trap_share)
    out = []
    for index in range(count):
        trap = index % 5 < traps_per_five
        goal = np.array([rng.uniform(8.0, 11.0), rng.uniform(-1.0, 1.0)])
        length = float(np.hypot(*goal))
        along = goal / length
        normal = np.array([-along[1], along[0]])
        obstacles: list[np.ndarray] = []
        if trap:
            radius_a = rng.uniform(0.8, 1.3) + MARGIN
            side = rng.choice([-1.0, 1.0])  # A's centre is on this side of the line
            fraction = rng.uniform(0.35, 0.65)
            centre_a = fraction * goal + side * rng.uniform(0.1, 0.3) * radius_a * normal
            radius_b = rng.uniform(0.7, 1.1) + MARGIN
            centre_b = centre_a - side * 0.8 * (radius_a + radius_b) * normal
            centre_b += rng.uniform(-0.3, 0.3) * along
            obstacles += [np.r_[centre_a, radius_a], np.r_[centre_b, radius_b]]
        wanted = int(rng.integers(3, 9))
        attempts = 0
        while len(obstacles) < wanted and attempts < 1000:
            attempts += 1
            radius = rng.uniform(0.4, 1.0) + MARGIN
            centre = rng.uniform(0.15, 0.85) * goal + rng.uniform(-3.5, 3.5) * normal
            disc = np.r_[centre, radius]
            if min(np.hypot(*centre), np.hypot(*(centre - goal))) < radius + 0.8:
                continue  # keeps the start and the goal free
            if trap and any(_disc_gap(disc, other) < 1.0 for other in obstacles[:2]):
                continue  # keeps the trap as constructed
            obstacles.append(disc)
        discs = np.array(obstacles)
        centres = np.column_stack([np.full(SLOTS, -100.0), -100.0 - 10.0 * np.arange(SLOTS)])
        radii = np.full(SLOTS, 0.1)
        centres[: len(discs)] = discs[:, :2]
        radii[: len(discs)] = discs[:, 2]
        speed = goal / (HORIZON * DT)
        x0 = np.r_[0.0, 0.0, speed + rng.uniform(-0.3, 0.3) * normal]
        line = np.linspace(0.0, 1.0, HORIZON + 1)[:, None] * goal
        states = np.column_stack([line, np.tile(speed, (HORIZON + 1, 1))])
        states[0] = x0
        guess = Iterate(scaled_controls=np.zeros((HORIZON, 2)), states=states)
        data = {"goal": goal, "line": line, "centres": centres.ravel(), "radii": radii}
        out.append(Instance(x0, data, guess, trap, discs))
    return out


def methods(candidates: int = 4) -> dict[str, tuple[str, dict | None]]:
    """Label -> (registered solver name, options) of every compared method."""
    return {
        "fatrop": ("fatrop", None),
        "ipopt": ("ipopt", None),
        "sqp": ("sqp", None),
        "multistart-ipopt": ("multistart-ipopt", None),
        f"multistart-fatrop ({candidates + 1})": ("multistart-fatrop", {"starts": candidates + 1}),
        "igwo": ("igwo", None),
        "pso": ("pso", None),
        "igwo+fatrop": ("igwo+fatrop", None),
        "pso+fatrop": ("pso+fatrop", None),
        "pso+fatrop k=2": ("pso+fatrop", {"candidates": 2}),
        f"igwo+fatrop k={candidates}": ("igwo+fatrop", {"candidates": candidates}),
        f"pso+fatrop k={candidates}": ("pso+fatrop", {"candidates": candidates}),
        f"pso+fatrop k={candidates}, swarm only": (
            "pso+fatrop",
            {"candidates": candidates, "keep_warm_start": False},
        ),
    }


def feasible(result: SolveResult) -> bool:
    """Feasible: the backend reports success and the judge's largest violation is ≤ 1e-6."""
    return bool(result.success) and result.max_violation <= FEASIBLE


def _solve_chunk(task: tuple) -> list[tuple[int, np.ndarray, np.ndarray, np.ndarray, float]]:
    """Solve the instances ``indices`` with every method (one process; builds its own backends)."""
    count, seed, trap_share, candidates, reference_starts, indices = task
    ocp = field_ocp()
    fields = instances(count, seed, trap_share)
    table = methods(candidates)
    backends = [uo.get_solver(ocp, name, options) for name, options in table.values()]
    # the long multistart only defines the best-known cost: its starts stop at 150 iterations
    reference = uo.get_solver(
        ocp, "multistart-fatrop", {"starts": reference_starts, "exact": {"max_iter": 150}}
    )
    warm = fields[indices[0]]  # builds (and for the swarms compiles, cached on disk) outside the timings
    p = ocp.parameters(warm.x0, warm.data)
    for backend in backends:
        backend.solve(p, warm.guess, np.random.default_rng(0))
    rows = []
    for i in indices:
        field = fields[i]
        p = ocp.parameters(field.x0, field.data)
        cost, ok, seconds = (
            np.full(len(backends), np.inf),
            np.zeros(len(backends), bool),
            np.zeros(len(backends)),
        )
        for j, backend in enumerate(backends):
            start = time.perf_counter()
            result = backend.solve(p, field.guess, np.random.default_rng([seed, i]))
            seconds[j] = time.perf_counter() - start
            ok[j] = feasible(result)
            cost[j] = result.cost if ok[j] else np.inf
        long = reference.solve(p, field.guess, np.random.default_rng([seed, i, 1]))
        rows.append((i, cost, ok, seconds, long.cost if feasible(long) else np.inf))
    return rows


def run(
    count: int,
    seed: int = 11,
    trap_share: float = 0.4,
    candidates: int = 4,
    reference_starts: int = REFERENCE_STARTS,
    workers: int = 1,
) -> dict:
    """Solve every instance with every method; return costs, feasibility, times, best-known costs.

    ``workers > 1`` splits the instances over that many processes (one solve per CPU at a time;
    each process times its own solves).
    """
    labels = list(methods(candidates))
    chunks = [list(range(count))[w::workers] for w in range(workers) if list(range(count))[w::workers]]
    tasks = [(count, seed, trap_share, candidates, reference_starts, chunk) for chunk in chunks]
    if len(tasks) == 1:
        rows = _solve_chunk(tasks[0])
    else:
        import multiprocessing

        with multiprocessing.get_context("spawn").Pool(len(tasks)) as pool:
            rows = [row for part in pool.map(_solve_chunk, tasks) for row in part]
    rows.sort(key=lambda row: row[0])
    cost = np.array([row[1] for row in rows])
    ok = np.array([row[2] for row in rows])
    seconds = np.array([row[3] for row in rows])
    best = np.minimum(np.min(cost, axis=1), np.array([row[4] for row in rows]))
    fields = instances(count, seed, trap_share)
    return {
        "labels": labels,
        "cost": cost,
        "ok": ok,
        "seconds": seconds,
        "best": best,
        "fields": fields,
        "reference_starts": reference_starts,
    }


def format_table(outcome: dict) -> str:
    """One row per method: best-known shares (all / trap / other), infeasible share, times."""
    labels, cost, ok, seconds, best = (outcome[k] for k in ("labels", "cost", "ok", "seconds", "best"))
    trap = np.array([f.trap for f in outcome["fields"]])
    reached = ok & (cost <= best[:, None] * (1.0 + WITHIN) + 1e-12)
    fatrop_median = float(np.median(seconds[:, labels.index("fatrop")]))
    count = len(best)
    lines = [
        f"{count} instances ({int(trap.sum())} traps), best-known = best feasible of every method "
        f"and a {outcome['reference_starts']}-start multistart-fatrop; {int(np.sum(~np.isfinite(best)))} "
        "without any feasible result",
        f"{'method':26s} {'best-known':>10s} {'trap':>7s} {'other':>7s} {'infeas.':>8s} "
        f"{'median ms':>10s} {'p90 ms':>8s} {'× fatrop':>9s}",
    ]

    def share(mask: np.ndarray) -> str:
        return f"{100.0 * float(np.mean(mask)):6.1f}%" if mask.size else "     -"

    for j, label in enumerate(labels):
        median = float(np.median(seconds[:, j]))
        lines.append(
            f"{label:26s} {share(reached[:, j]):>10s} {share(reached[trap, j]):>7s} "
            f"{share(reached[~trap, j]):>7s} {share(~ok[:, j]):>8s} {1e3 * median:10.1f} "
            f"{1e3 * float(np.percentile(seconds[:, j], 90)):8.1f} {median / fatrop_median:9.2f}"
        )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> None:
    """Print the table (``--instances`` for a reduced run)."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--instances", type=int, default=200, help="number of obstacle fields")
    parser.add_argument("--seed", type=int, default=11, help="seed of the generator")
    parser.add_argument("--trap", type=float, default=0.4, help="share of trap instances (multiple of 0.2)")
    parser.add_argument("--candidates", type=int, default=4, help="k of the candidate hybrid")
    parser.add_argument("--reference-starts", type=int, default=REFERENCE_STARTS)
    parser.add_argument("--workers", type=int, default=2, help="processes (default 2: one per core)")
    args = parser.parse_args(argv if argv is not None else [])
    if args.instances < 1 or args.workers < 1:
        parser.error("--instances and --workers must be >= 1")
    start = time.perf_counter()
    outcome = run(args.instances, args.seed, args.trap, args.candidates, args.reference_starts, args.workers)
    print(format_table(outcome))
    print(
        f"({time.perf_counter() - start:.0f} s wall; python -m benchmarks.bench_nonconvex "
        f"--instances {args.instances} --seed {args.seed} --workers {args.workers})"
    )


if __name__ == "__main__":
    import sys

    main(sys.argv[1:])
