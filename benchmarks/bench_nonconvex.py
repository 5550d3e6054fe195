"""Where the metaheuristic warm start earns its place: seeded obstacle fields, several homotopy classes.

Problem (one :class:`uuv_ocp.Ocp`, built and compiled once; every instance is parameter data):
a planar double integrator ``p̈ = a`` (a point vehicle of 0.2 m radius, included in the
obstacle radii), ``N = 20`` intervals of ``dt = 0.375`` s (7.5 s), acceleration box
``|a_i| ≤ 1`` m/s² and rate bound ``|ȧ_i| ≤ 2`` m/s³, stage cost
``Σ_{k≥1} 0.3²‖p_k − r_k‖² + 0.5²‖a_k‖²`` against the straight line ``r`` from start to goal
at constant speed, terminal cost ``3²‖p_N − goal‖² + ‖v_N‖²``, and up to 8 circular obstacles
``‖p_k − c_{i,k}‖² ≥ ρ_i²`` on nodes 1..N (centres per node and radii are parameters; unused
slots sit far away), one local optimum per homotopy class.

Instances (:func:`instances`, seeded): start at the origin moving along the line at its speed
plus a lateral velocity ``U(−0.3, 0.3)`` m/s, goal at ``(U(8, 11), U(−1, 1))`` m, 3–8
obstacles of radius 0.4–1.0 m (+ margin) placed near the line.  A fixed share (``--trap``,
default 40 %) are *traps*: an obstacle A (radius 0.8–1.3 m) straddles the line, its centre
0.1–0.3 radii off it, and a blocker B (0.7–1.1 m) overlaps A on the side of the line, so the
straight line lies on the side where the path must go around both — the worse homotopy class —
while a gradient solver started on the line is pushed to it (away from A's centre).  With
``--moving`` every obstacle moves at a constant velocity (speed ``U(0, 0.4)`` m/s, random
heading; a trap's A and B share one velocity and are placed where they straddle the line when
the vehicle passes them); the instances of a seed are the static ones plus the velocities.

Methods (:func:`methods`): fatrop from the straight-line guess (states on the line, zero
acceleration); multistart-fatrop with 5 and 9 starts (the straight line first, see
:mod:`uuv_ocp.solvers.multistart`; multistart-ipopt, 4× slower than multistart-fatrop (5) for
the same share on 50 fields, is left out to keep 500 instances within the time box); igwo and
pso alone; the hybrids igwo+fatrop and pso+fatrop at their defaults (the exact solver from the
swarm's best plan and from the best ``classes = 4`` homotopy-class guesses of
:mod:`uuv_ocp.solvers.homotopy`, the obstacles given by :func:`geometry`), and pso+fatrop with
``classes=0`` (the swarm's plan only: the hybrid before the class starts) and with
``skip_swarm_class=False`` (every class start run, the default before the skip), and with
``initial_population="classes"`` (half of the swarm's initial particles follow the class paths).
Every method gets the same straight-line warm start and, for the random parts, the generator
``default_rng([seed, i])`` on instance ``i``.  The best-known cost of an instance is the best
feasible cost found by any of them or by a 32-start multistart-fatrop (its starts capped at
150 iterations: it only has to find the best class).

Columns: ``best-known`` = share of instances whose result is feasible (``success`` and
``max_violation ≤ 1e-6``) and within 1 % of the best-known cost, with its Wilson 95 % interval
(``trap`` / ``other``: the same on the two kinds of instance); ``infeasible`` = share not
feasible; median and p90 wall time of ``backend.solve`` per instance (builds and compilation
excluded), and the median relative to single fatrop's.  Below the table: the best hybrid minus
the best multistart (by share reaching the best-known cost), with a paired bootstrap 95 %
interval over instances (seeded, :func:`paired_bootstrap`).

``--out FILE`` appends one JSON line per finished instance (with a SHA-256 checksum of its
content and the run's configuration); a rerun with the same ``--out`` skips the instances
already there and recomputes any whose line is corrupted or from another configuration;
``--report`` prints the table of the rows there without solving anything.  Ctrl-C stops after
the current instance and prints the table of those done.

Run: ``python -m benchmarks.bench_nonconvex [--instances 500] [--seed 11] [--trap 0.4]
[--moving] [--workers 1] [--out FILE]`` (part of ``make bench``).
"""

from __future__ import annotations

import argparse
import hashlib
import json
import math
import os
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import casadi as ca
import numpy as np

import uuv_ocp as uo
from uuv_ocp.progress import ProgressBar
from uuv_ocp.solvers.homotopy import Geometry
from uuv_ocp.solvers.result import Iterate, SolveResult

HORIZON, DT = 20, 0.375
SLOTS = 8  # obstacle slots of the Ocp
MARGIN = 0.2  # vehicle radius (m), added to every obstacle radius
WITHIN = 0.01  # "reaches the best-known cost": within 1 %
FEASIBLE = 1e-6  # largest violation of a feasible result
REFERENCE_STARTS = 32
MAX_SPEED = 0.4  # largest obstacle speed with --moving (m/s)
Z95 = 1.959963984540054  # standard normal quantile of 0.975
BOOTSTRAP = 10_000  # resamples of the paired bootstrap


def field_ocp() -> uo.Ocp:
    """Declare the planar double integrator among up to ``SLOTS`` circular obstacles (parameters)."""
    ocp = uo.Ocp(horizon=HORIZON, dt=DT, name="obstacle_field")
    pos = ocp.state("pos", 2)
    vel = ocp.state("vel", 2)
    acc = ocp.control("acc", 2, lower=-1.0, upper=1.0, max_rate=2.0)
    goal = ocp.parameter("goal", 2)
    line = ocp.parameter("line", 2, stagewise=True)
    centres = ocp.parameter("centres", 2 * SLOTS, stagewise=True)  # per node: moving obstacles
    radii = ocp.parameter("radii", SLOTS)
    ocp.set_der(pos, vel)
    ocp.set_der(vel, acc)
    ocp.add_stage_cost(residual=ca.vertcat(0.3 * (pos - line), 0.5 * acc), start=1)
    ocp.add_terminal_cost(residual=ca.vertcat(3.0 * (pos - goal), vel))
    for i in range(SLOTS):
        ocp.subject_to(ca.sumsqr(pos - centres[2 * i : 2 * i + 2]) >= radii[i] ** 2)
    return ocp


def geometry(ocp: uo.Ocp) -> Callable[[np.ndarray], Geometry]:
    """Return the hybrids' ``geometry`` option: the discs of instance ``p`` read from its parameters."""
    entries = ocp.spec().layout.entries
    where_centres, where_radii = entries["centres"][0], entries["radii"][0]

    def provider(p: np.ndarray) -> Geometry:
        centres = np.asarray(p[where_centres], dtype=float).reshape(HORIZON + 1, SLOTS, 2)
        radii = np.broadcast_to(np.asarray(p[where_radii], dtype=float), (HORIZON + 1, SLOTS))
        return Geometry(np.concatenate([centres, radii[:, :, None]], axis=2), (0, 1), (2, 3), DT)

    return provider


@dataclass(frozen=True)
class Instance:
    """One obstacle field: initial state, parameter data, straight-line guess, and its kind."""

    x0: np.ndarray
    data: dict
    guess: Iterate
    trap: bool
    obstacles: np.ndarray  # (n, 3): centre x, centre y (at t = 0), radius with margin
    velocities: np.ndarray  # (n, 2): obstacle velocities (m/s), zero unless moving


def _disc_gap(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.hypot(*(a[:2] - b[:2])) - a[2] - b[2])


def instances(count: int, seed: int = 11, trap_share: float = 0.4, moving: bool = False) -> list[Instance]:
    """``count`` seeded obstacle fields; the first ``round(trap_share * 5)`` of every 5 are traps.

    With ``moving`` the same fields (same generator draws) plus a velocity per obstacle, drawn
    from a second generator; the obstacles' centres at the time the vehicle passes them (at
    its constant speed along the line) are the static field's.
    """
    rng = np.random.default_rng(seed)
    motion = np.random.default_rng([seed, 1])
    traps_per_five = round(5 * trap_share)
    times = DT * np.arange(HORIZON + 1)
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
        velocities = np.zeros((len(discs), 2))
        passing = np.zeros(len(discs))
        if moving:
            speed_draw = motion.uniform(0.0, MAX_SPEED, len(discs))
            heading = motion.uniform(-np.pi, np.pi, len(discs))
            velocities = speed_draw[:, None] * np.column_stack([np.cos(heading), np.sin(heading)])
            if trap:
                velocities[1] = velocities[0]  # A and B move together: the trap stays closed
            # each disc is where the static field has it when the vehicle passes it
            passing = np.clip(discs[:, :2] @ along / length, 0.0, 1.0) * HORIZON * DT
            if trap:
                passing[1] = passing[0]
            discs = discs.copy()
            discs[:, :2] -= velocities * passing[:, None]
        track = np.column_stack([np.full(SLOTS, -100.0), -100.0 - 10.0 * np.arange(SLOTS)])
        centres = np.tile(track, (HORIZON + 1, 1, 1))
        centres[:, : len(discs)] = discs[None, :, :2] + times[:, None, None] * velocities[None]
        radii = np.full(SLOTS, 0.1)
        radii[: len(discs)] = discs[:, 2]
        speed = goal / (HORIZON * DT)
        x0 = np.r_[0.0, 0.0, speed + rng.uniform(-0.3, 0.3) * normal]
        line = np.linspace(0.0, 1.0, HORIZON + 1)[:, None] * goal
        states = np.column_stack([line, np.tile(speed, (HORIZON + 1, 1))])
        states[0] = x0
        guess = Iterate(scaled_controls=np.zeros((HORIZON, 2)), states=states)
        data = {"goal": goal, "line": line, "centres": centres.reshape(HORIZON + 1, -1), "radii": radii}
        out.append(Instance(x0, data, guess, trap, discs, velocities))
    return out


def methods(provider: Callable[[np.ndarray], Geometry] | None = None) -> dict[str, tuple[str, dict | None]]:
    """Label -> (registered solver name, options) of every compared method.

    ``provider`` is the hybrids' ``geometry`` option (:func:`geometry`); ``None`` leaves it out
    (the labels do not depend on it).
    """
    known = {"geometry": provider} if provider is not None else {}
    return {
        "fatrop": ("fatrop", None),
        "multistart-fatrop (5)": ("multistart-fatrop", {"starts": 5}),
        "multistart-fatrop (9)": ("multistart-fatrop", {"starts": 9}),
        "igwo": ("igwo", None),
        "pso": ("pso", None),
        "igwo+fatrop": ("igwo+fatrop", dict(known)),
        "pso+fatrop": ("pso+fatrop", dict(known)),
        "pso+fatrop classes=0": ("pso+fatrop", {"classes": 0}),
        "pso+fatrop no skip": ("pso+fatrop", {**known, "skip_swarm_class": False}),
        "pso+fatrop pop=classes": ("pso+fatrop", {**known, "initial_population": "classes"}),
    }


def feasible(result: SolveResult) -> bool:
    """Feasible: the backend reports success and the judge's largest violation is ≤ 1e-6."""
    return bool(result.success) and result.max_violation <= FEASIBLE


# ------------------------------------------------------------------ statistics
def wilson(successes: int, trials: int, z: float = Z95) -> tuple[float, float]:
    """Wilson score interval of a binomial proportion (default 95 %): ``(low, high)``."""
    if trials < 1:
        raise ValueError(f"trials must be >= 1, got {trials}")
    if not 0 <= successes <= trials:
        raise ValueError(f"successes must be in [0, {trials}], got {successes}")
    share = successes / trials
    denominator = 1.0 + z * z / trials
    centre = (share + z * z / (2 * trials)) / denominator
    half = z * math.sqrt(share * (1.0 - share) / trials + z * z / (4 * trials * trials)) / denominator
    return max(0.0, centre - half), min(1.0, centre + half)


def paired_bootstrap(
    a: np.ndarray, b: np.ndarray, seed: int = 0, resamples: int = BOOTSTRAP, level: float = 0.95
) -> tuple[float, float, float]:
    """Mean of ``a − b`` over paired instances and its percentile bootstrap interval.

    The instances are resampled with replacement (the same rows for ``a`` and ``b``: the
    pairing keeps what the two methods share, e.g. hard instances), ``resamples`` times, from
    ``numpy.random.default_rng(seed)``.  Returns ``(mean, low, high)``.
    """
    first, second = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    if first.ndim != 1 or first.shape != second.shape or first.size < 1:
        raise ValueError(
            f"a and b must be equal-length 1-D arrays, got shapes {first.shape} and {second.shape}"
        )
    difference = first - second
    rng = np.random.default_rng(seed)
    rows = rng.integers(0, difference.size, size=(resamples, difference.size))
    means = difference[rows].mean(axis=1)
    tail = 100.0 * (1.0 - level) / 2.0
    low, high = np.percentile(means, [tail, 100.0 - tail])
    return float(difference.mean()), float(low), float(high)


# ------------------------------------------------------------------ results file
def _checksum(payload: dict) -> str:
    return hashlib.sha256(json.dumps(payload, sort_keys=True).encode()).hexdigest()


def encode_row(config: dict, row: dict) -> str:
    """One JSON line: the row, the run's configuration and a SHA-256 of both."""
    payload = {"config": config, **row}
    return json.dumps({**payload, "sha256": _checksum(payload)})


def read_rows(path: Path, config: dict) -> tuple[dict[int, dict], int]:
    """Rows of ``path`` whose checksum and configuration match: ``({index: row}, rejected lines)``.

    A line that is not JSON, lacks or fails its checksum, or was written by another
    configuration is not trusted (counted in ``rejected``; its instance is solved again).
    """
    rows: dict[int, dict] = {}
    rejected = 0
    if not path.exists():
        return rows, rejected
    for line in path.read_text().splitlines():
        if not line.strip():
            continue
        try:
            record = json.loads(line)
            digest = record.pop("sha256")
            valid = isinstance(record, dict) and digest == _checksum(record) and record["config"] == config
        except (ValueError, KeyError, TypeError, AttributeError):
            valid = False
        if not valid:
            rejected += 1
            continue
        record.pop("config")
        rows[int(record["index"])] = record
    return rows, rejected


# ------------------------------------------------------------------ solving
class Runner:
    """Every method's backend on the one Ocp (built once; the first solve compiles)."""

    def __init__(self, config: dict) -> None:
        self.config = config
        self.ocp = field_ocp()
        self.fields = instances(config["instances"], config["seed"], config["trap"], config["moving"])
        table = methods(geometry(self.ocp))
        self.backends = [uo.get_solver(self.ocp, name, options) for name, options in table.values()]
        # the long multistart only defines the best-known cost: its starts stop at 150 iterations
        self.reference = uo.get_solver(
            self.ocp,
            "multistart-fatrop",
            {"starts": config["reference_starts"], "exact": {"max_iter": 150}},
        )
        warm = self.fields[0]  # builds (and for the swarms compiles) outside the timings
        p = self.ocp.parameters(warm.x0, warm.data)
        for backend in self.backends:
            backend.solve(p, warm.guess, np.random.default_rng(0))

    def solve(self, i: int) -> dict:
        """Solve instance ``i`` with every method and the reference; one row of the results file."""
        field, seed = self.fields[i], self.config["seed"]
        p = self.ocp.parameters(field.x0, field.data)
        cost, ok, seconds = [], [], []
        for backend in self.backends:
            start = time.perf_counter()
            result = backend.solve(p, field.guess, np.random.default_rng([seed, i]))
            seconds.append(time.perf_counter() - start)
            ok.append(feasible(result))
            cost.append(float(result.cost) if ok[-1] else None)
        long = self.reference.solve(p, field.guess, np.random.default_rng([seed, i, 1]))
        reference = float(long.cost) if feasible(long) else None
        return {"index": i, "cost": cost, "ok": ok, "seconds": seconds, "reference": reference}


_RUNNER: Runner | None = None


def _start_worker(config: dict) -> None:
    global _RUNNER
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
    _RUNNER = Runner(config)


def _solve_in_worker(i: int) -> dict:
    assert _RUNNER is not None
    return _RUNNER.solve(i)


def run(config: dict, out: Path | None = None, workers: int = 1, progress: bool = True) -> dict:
    """Solve the instances not yet in ``out`` (every one without it); return the outcome.

    Rows are appended to ``out`` as they finish (flushed), so an interrupted run loses at most
    the instances in flight.  Ctrl-C stops the run; the outcome then holds the rows done.
    """
    done, rejected = read_rows(out, config) if out is not None else ({}, 0)
    todo = [i for i in range(config["instances"]) if i not in done]
    interrupted = False
    handle = out.open("a") if out is not None else None
    try:
        with ProgressBar(config["instances"], "obstacle fields", progress, initial=len(done)) as bar:
            if workers == 1:
                runner = Runner(config) if todo else None
                results = (runner.solve(i) for i in todo) if runner is not None else iter(())
                pool = None
            else:
                import multiprocessing

                pool = multiprocessing.get_context("spawn").Pool(workers, _start_worker, (config,))
                results = pool.imap_unordered(_solve_in_worker, todo)
            try:
                for row in results:
                    done[row["index"]] = row
                    if handle is not None:
                        handle.write(encode_row(config, row) + "\n")
                        handle.flush()
                    bar.update()
            except KeyboardInterrupt:
                interrupted = True
            finally:
                if pool is not None:
                    pool.terminate()
    finally:
        if handle is not None:
            handle.close()
    return summary(config, done, rejected, interrupted)


def summary(config: dict, done: dict[int, dict], rejected: int = 0, interrupted: bool = False) -> dict:
    """Return the outcome of the rows ``done`` (``{index: row}``): arrays over instances × methods."""
    labels = list(methods())
    indices = sorted(done)
    fields = instances(config["instances"], config["seed"], config["trap"], config["moving"])

    def matrix(key: str, empty: float) -> np.ndarray:
        return np.array([[empty if v is None else v for v in done[i][key]] for i in indices], dtype=float)

    cost = matrix("cost", np.inf).reshape(len(indices), len(labels))
    reference = np.array([np.inf if done[i]["reference"] is None else done[i]["reference"] for i in indices])
    return {
        "labels": labels,
        "indices": indices,
        "cost": cost,
        "ok": np.array([done[i]["ok"] for i in indices], dtype=bool).reshape(len(indices), len(labels)),
        "seconds": matrix("seconds", np.nan).reshape(len(indices), len(labels)),
        "best": np.minimum(np.min(cost, axis=1, initial=np.inf), reference),
        "trap": np.array([fields[i].trap for i in indices], dtype=bool),
        "config": config,
        "rejected": rejected,
        "interrupted": interrupted,
    }


def reached(outcome: dict) -> np.ndarray:
    """(instances, methods) booleans: feasible and within 1 % of the best-known cost."""
    cost, ok, best = outcome["cost"], outcome["ok"], outcome["best"]
    return ok & (cost <= best[:, None] * (1.0 + WITHIN) + 1e-12)


def format_table(outcome: dict, bootstrap_seed: int = 0) -> str:
    """One row per method (best-known share with Wilson CI, trap / other, infeasible, times), and the lead."""
    labels, seconds, best, trap = (outcome[k] for k in ("labels", "seconds", "best", "trap"))
    hit, ok = reached(outcome), outcome["ok"]
    count = len(best)
    if count == 0:
        return "no instance solved"
    fatrop_median = float(np.median(seconds[:, labels.index("fatrop")]))
    config = outcome["config"]
    lines = [
        f"{count} instances ({int(trap.sum())} traps, {'moving' if config['moving'] else 'static'} "
        "obstacles, "
        f"seed {config['seed']}), best-known = best feasible of every method and a "
        f"{config['reference_starts']}-start multistart-fatrop; {int(np.sum(~np.isfinite(best)))} without "
        "any feasible result",
        f"{'method':24s} {'best-known':>10s} {'95% CI':>13s} {'trap':>7s} {'other':>7s} {'infeas.':>8s} "
        f"{'median ms':>10s} {'p90 ms':>8s} {'× fatrop':>9s}",
    ]

    def share(mask: np.ndarray) -> str:
        return f"{100.0 * float(np.mean(mask)):6.1f}%" if mask.size else "     -"

    for j, label in enumerate(labels):
        median = float(np.median(seconds[:, j]))
        low, high = wilson(int(hit[:, j].sum()), count)
        lines.append(
            f"{label:24s} {share(hit[:, j]):>10s} {f'[{100 * low:.1f}, {100 * high:.1f}]':>13s} "
            f"{share(hit[trap, j]):>7s} {share(hit[~trap, j]):>7s} {share(~ok[:, j]):>8s} "
            f"{1e3 * median:10.1f} {1e3 * float(np.percentile(seconds[:, j], 90)):8.1f} "
            f"{median / fatrop_median:9.2f}"
        )
    hybrids = [j for j, label in enumerate(labels) if "+" in label]
    multistarts = [j for j, label in enumerate(labels) if label.startswith("multistart")]
    h = max(hybrids, key=lambda j: hit[:, j].mean())
    m = max(multistarts, key=lambda j: hit[:, j].mean())
    mean, low, high = paired_bootstrap(hit[:, h], hit[:, m], bootstrap_seed)
    lines.append(
        f"best hybrid ({labels[h]}) − best multistart ({labels[m]}): {100 * mean:+.1f} points, "
        f"paired bootstrap 95% CI [{100 * low:+.1f}, {100 * high:+.1f}] ({BOOTSTRAP} resamples, seed "
        f"{bootstrap_seed})"
    )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> None:
    """Print the table (``--instances`` for a reduced run; ``--out`` to keep and resume rows)."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--instances", type=int, default=500, help="number of obstacle fields")
    parser.add_argument("--seed", type=int, default=11, help="seed of the generator")
    parser.add_argument("--trap", type=float, default=0.4, help="share of trap instances (multiple of 0.2)")
    parser.add_argument("--moving", action="store_true", help="obstacles move at constant velocities")
    parser.add_argument("--reference-starts", type=int, default=REFERENCE_STARTS)
    parser.add_argument("--workers", type=int, default=1, help="processes (each solve is timed in its own)")
    parser.add_argument("--out", type=Path, default=None, help="JSON-lines file of finished instances")
    parser.add_argument("--no-progress", action="store_true", help="draw no progress bar")
    parser.add_argument("--report", action="store_true", help="only print the table of the rows in --out")
    args = parser.parse_args(argv if argv is not None else [])
    if args.instances < 1 or args.workers < 1:
        parser.error("--instances and --workers must be >= 1")
    config = {
        "instances": args.instances,
        "seed": args.seed,
        "trap": args.trap,
        "moving": args.moving,
        "reference_starts": args.reference_starts,
        "methods": list(methods()),
    }
    start = time.perf_counter()
    if args.report:
        if args.out is None:
            parser.error("--report needs --out")
        rows, rejected = read_rows(args.out, config)
        outcome = summary(config, rows, rejected, interrupted=len(rows) < args.instances)
    else:
        outcome = run(config, args.out, args.workers, not args.no_progress)
    if outcome["rejected"]:
        print(f"{outcome['rejected']} line(s) of {args.out} rejected (corrupted or another configuration)")
    if outcome["interrupted"]:
        print(f"not finished: {len(outcome['indices'])} of {args.instances} instances done")
    print(format_table(outcome))
    print(
        f"({time.perf_counter() - start:.0f} s wall, load {os.getloadavg()[0]:.1f}; python -m "
        f"benchmarks.bench_nonconvex --instances {args.instances} --seed {args.seed} --workers {args.workers}"
        f"{' --moving' if args.moving else ''})"
    )
    if outcome["interrupted"] and not args.report:
        sys.exit(130)  # the rows so far are saved and the table printed; a script still sees the stop


if __name__ == "__main__":
    import sys

    main(sys.argv[1:])
