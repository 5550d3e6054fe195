"""The C real-time iteration against the horizon and the state size, and against another checkout.

Every configuration (vehicle, horizon N, solver and options) runs in a worker process of its own,
built first (its C step compiled, the cold first step taken); then each round asks every worker
for one closed loop from the vehicle's start, one worker after the other, so the machine's drift
falls on all rows alike (two cores shared with other jobs here: only ratios within one run mean
something; the load is printed beside the table).  A row's figure is the median over the rounds
of the per-loop median ``NMPC.step`` wall time (ms), the steps after the cold first one.

Vehicles: ``rexrov`` (the paper's 3-DOF RexROV on s2: 6 states, 3 controls), ``bluerov2`` (the
BlueROV2 Heavy survey of ``examples/bluerov2_depth.py``: 12 states, 6 generalised forces),
``bluerov2-thrusters`` (the same survey, the 8 thruster forces as controls).  The C step lifts
the previous control into the state (rate bounds), so its stages have 6 + 3, 12 + 6 and 12 + 8
states.

Run:
``python -m benchmarks.bench_rti_scaling`` (the scaling table: N = 10, 20, 40, 80 and the three
vehicles, ``sqp-rti`` rti and converged and compiled fatrop, with the growth exponent of a
log-log fit over N = 20..80);
``python -m benchmarks.bench_rti_scaling --against /tmp/rti_base/src`` (the BlueROV2 survey and
s2 at N = 20: this checkout's ``sqp-rti`` against the package in that ``src`` folder, rti and
converged, interleaved; ``--rounds``, ``--steps``);
``--breakdown`` (with ``--vehicle``): the RTI step against N split into linearisation, QP and
the Python around them, each with its growth exponent (:func:`breakdown`).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import select
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
#: the C step (``qpsol="hpipm-ocp"``) in the two modes
RTI = {"qpsol": "hpipm-ocp"}
CONVERGED = {"qpsol": "hpipm-ocp", "mode": "converged"}
SOLVERS = (("sqp-rti rti", "sqp-rti", RTI), ("sqp-rti converged", "sqp-rti", CONVERGED))
FATROP = ("fatrop compiled", "fatrop", {"compiled": True})
VEHICLES = ("rexrov", "bluerov2", "bluerov2-thrusters")
HORIZONS = (10, 20, 40, 80)


def problem_and_start(vehicle: str, horizon: int) -> tuple[object, np.ndarray]:
    """Return the tracking problem of ``vehicle`` at horizon ``horizon`` (dt = 0.1 s) and its start."""
    import uuv_ocp as uo

    if vehicle == "rexrov":
        problem = uo.TrackingProblem(uo.Vehicle.rexrov(), uo.Reference.paper("s2"), horizon=horizon, dt=0.1)
        return problem, problem.reference.initial_state(0.0)
    from benchmarks.bench_rti import _bluerov2_survey

    return _bluerov2_survey(horizon, thrusters=vehicle == "bluerov2-thrusters")


def closed_loop(controller: object, problem: object, start: np.ndarray, steps: int) -> dict:
    """One closed loop from ``start``: median step wall time and the C step's clocks (ms)."""
    import uuv_ocp as uo

    vehicle = problem.vehicle
    # the thruster vehicle's control is the thruster forces: its plant maps them through T
    thrusters = getattr(vehicle, "thrusters", None) is not None
    dynamics = vehicle.thruster_dynamics if thrusters else vehicle.dynamics_function()
    plant = uo.rk4_step(dynamics, problem.dt, 10)
    still = np.zeros(plant.size1_in(2))
    controller.reset()
    state, control = start.copy(), np.zeros(problem.spec().control_size)
    wall, cpu, lin, qp, eq, fast, sqp, ipm = [], [], [], [], [], [], [], []
    for k in range(steps):
        begin, begin_cpu = time.perf_counter(), time.thread_time()
        output = controller.step(state, k * problem.dt, control)
        elapsed, elapsed_cpu = time.perf_counter() - begin, time.thread_time() - begin_cpu
        control = output.control
        if k:
            wall.append(elapsed)
            cpu.append(elapsed_cpu)
            info = getattr(getattr(controller, "_deferred", None), "info", None)
            fast.append(bool(getattr(output, "fast_path", False)))
            if fast[-1] and info is not None:
                lin.append(info[6])
                qp.append(info[7])
                eq.append(info[4] == 0)
                sqp.append(info[0])  # Gauss-Newton iterations of the step
                ipm.append(info[4])  # HPIPM iterations of its last QP
        state = np.array(plant(state, control, still)).ravel()

    def median(values: list) -> float:
        return 1e3 * float(np.median(values)) if values else math.nan

    return {
        "wall": median(wall),
        "cpu": median(cpu),
        "lin": median(lin),
        "qp": median(qp),
        "equality_first": float(np.mean(eq)) if eq else math.nan,
        # the share of steps the C step answered (the rest: solve()'s chain), its iterations
        "fast": float(np.mean(fast)) if fast else math.nan,
        "sqp_iterations": float(np.mean(sqp)) if sqp else math.nan,
        "qp_iterations": float(np.median(ipm)) if ipm else math.nan,
    }


def worker(config: dict) -> None:
    """``--worker CONFIG``: build one row, then answer each ``round`` line with one loop's JSON."""
    import uuv_ocp as uo

    problem, start = problem_and_start(config["vehicle"], config["horizon"])
    controller = uo.NMPC(problem, config["solver"], options=config["options"])
    closed_loop(controller, problem, start, 3)  # the cold step, the C step's build
    print(json.dumps({"ready": True}), flush=True)
    for line in sys.stdin:
        if line.strip() != "round":
            break
        print(json.dumps(closed_loop(controller, problem, start, config["steps"])), flush=True)


#: seconds a worker may take to build its row (``--build-timeout``; ``None``: no limit)
BUILD_TIMEOUT: float | None = None
#: rows left out and why (label: reason), filled by :func:`interleaved`
LEFT_OUT: dict[str, str] = {}


def interleaved(configs: dict[str, dict], rounds: int) -> dict[str, dict]:
    """Run every configuration's worker, ``rounds`` loops each, interleaved; median per row.

    A worker that fails to build, or takes longer than :data:`BUILD_TIMEOUT` seconds (compiled
    fatrop's JIT of the unrolled NLP at N = 80), is left out (:data:`LEFT_OUT` says why).
    """
    workers = {}
    for label, config in configs.items():
        path = [config.pop("src", None) or str(ROOT / "src"), str(ROOT)]
        env = {**os.environ, "PYTHONPATH": os.pathsep.join(path)}
        process = subprocess.Popen(
            [sys.executable, "-m", "benchmarks.bench_rti_scaling", "--worker", json.dumps(config)],
            cwd=ROOT,
            env=env,
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            text=True,
        )
        assert process.stdout is not None
        begin = time.perf_counter()
        ready, _, _ = select.select([process.stdout], [], [], BUILD_TIMEOUT)
        if not ready:
            process.kill()
            process.wait()
            LEFT_OUT[label] = f"not built within {BUILD_TIMEOUT:.0f} s"
            print(f"{label}: {LEFT_OUT[label]}", file=sys.stderr, flush=True)
            continue
        if not process.stdout.readline():  # a build failed: the row is left out
            LEFT_OUT[label] = "the build failed"
            print(f"{label}: worker failed", file=sys.stderr)
            continue
        print(f"{label}: built in {time.perf_counter() - begin:.0f} s", file=sys.stderr, flush=True)
        workers[label] = process
    samples: dict[str, list[dict]] = {label: [] for label in workers}
    try:
        for round_index in range(rounds):
            order = list(workers.items())
            for label, process in order if round_index % 2 == 0 else order[::-1]:
                assert process.stdin is not None and process.stdout is not None
                process.stdin.write("round\n")
                process.stdin.flush()
                samples[label].append(json.loads(process.stdout.readline()))
    finally:
        for process in workers.values():
            if process.stdin is not None:
                process.stdin.close()
            process.wait(timeout=120)
    rows = {}
    for label, values in samples.items():
        rows[label] = {key: float(np.median([v[key] for v in values])) for key in values[0]}
        rows[label]["range"] = (min(v["cpu"] for v in values), max(v["cpu"] for v in values))
    return rows


def growth_exponent(horizons: list[int], times: list[float]) -> float:
    """Slope of the least-squares line through (log N, log time) over N = 20..80."""
    pairs = [(n, t) for n, t in zip(horizons, times, strict=True) if n >= 20 and np.isfinite(t)]
    if len(pairs) < 2:
        return math.nan
    x, y = np.log([n for n, _ in pairs]), np.log([t for _, t in pairs])
    return float(np.polyfit(x, y, 1)[0])


def scaling(
    rounds: int, steps: int, horizons: tuple[int, ...], vehicles: tuple[str, ...], fatrop: bool = True
) -> str:
    """Return the scaling table (markdown): step ms per vehicle, solver and N, with the exponent."""
    configs = {}
    solvers = (*SOLVERS, FATROP) if fatrop else SOLVERS
    for vehicle in vehicles:
        for label, solver, options in solvers:
            for horizon in horizons:
                configs[(vehicle, label, horizon)] = {
                    "vehicle": vehicle,
                    "horizon": horizon,
                    "solver": solver,
                    "options": options,
                    "steps": steps,
                }
    rows = interleaved({json.dumps(key): dict(config) for key, config in configs.items()}, rounds)
    # wall and thread CPU: on a shared machine a step longer than about a millisecond is
    # preempted, so the wall exponent can be the load's (docs/benchmarks.md, issue 29)
    header = (
        "| vehicle | solver | "
        + " | ".join(f"N = {n}, wall (CPU)" for n in horizons)
        + " | exponent (N = 20..80), wall (CPU) |"
    )
    lines = [header, "|" + "---|" * (len(horizons) + 3)]
    for vehicle in vehicles:
        for label, _, _ in solvers:
            found = [rows.get(json.dumps([vehicle, label, n]), {}) for n in horizons]
            walls = [row.get("wall", math.nan) for row in found]
            cpus = [row.get("cpu", math.nan) for row in found]
            cells = " | ".join(
                "–" if not np.isfinite(w) else f"{w:.3f} ({c:.3f})" for w, c in zip(walls, cpus, strict=True)
            )
            wall_exponent, cpu_exponent = (growth_exponent(list(horizons), t) for t in (walls, cpus))
            exponents = f"{wall_exponent:.2f} ({cpu_exponent:.2f})"
            lines.append(f"| {vehicle} | {label} | {cells} | {exponents} |")
    for key, reason in LEFT_OUT.items():
        vehicle, label, horizon = json.loads(key)
        lines.append(f"\n{vehicle}, {label}, N = {horizon}: {reason}")
    return "\n".join(lines)


def against(src: str, rounds: int, steps: int, vehicles: tuple[str, ...] = ("bluerov2", "rexrov")) -> str:
    """Compare this checkout's ``sqp-rti`` with the package in ``src`` (BlueROV2 survey and s2, N = 20)."""
    configs = {}
    for vehicle in vehicles:
        for label, solver, options in SOLVERS:
            for who, folder in (("this", None), ("baseline", src)):
                configs[f"{vehicle} | {label} | {who}"] = {
                    "vehicle": vehicle,
                    "horizon": 20,
                    "solver": solver,
                    "options": options,
                    "steps": steps,
                    "src": folder,
                }
    rows = interleaved(configs, rounds)
    lines = [
        "| vehicle | mode | baseline ms (CPU) | this ms (CPU) | × baseline (CPU) "
        "| this: linearise / QP ms in C |",
        "|---|---|---|---|---|---|",
    ]
    for vehicle in vehicles:
        for label, _, _ in SOLVERS:
            base, this = rows.get(f"{vehicle} | {label} | baseline"), rows.get(f"{vehicle} | {label} | this")
            if base is None or this is None:
                continue
            lines.append(
                f"| {vehicle} | {label} | {base['wall']:.3f} ({base['cpu']:.3f}) | {this['wall']:.3f} "
                f"({this['cpu']:.3f}) | {this['wall'] / base['wall']:.2f} "
                f"({this['cpu'] / base['cpu']:.2f}) | "
                f"{this['lin']:.3f} / {this['qp']:.3f} |"
            )
    return "\n".join(lines)


def compare_options(vehicle: str, horizon: int, variants: dict[str, dict], rounds: int, steps: int) -> str:
    """Run closed loops of ``sqp-rti`` under each of ``variants`` (label: options), interleaved."""
    configs = {
        label: {"vehicle": vehicle, "horizon": horizon, "solver": "sqp-rti", "options": options}
        for label, options in variants.items()
    }
    for config in configs.values():
        config["steps"] = steps
    rows = interleaved(configs, rounds)
    first = next(iter(rows.values()))
    lines = [
        f"| {vehicle}, N = {horizon} | wall ms | thread CPU ms (range) | × first | in C: linearise / QP ms "
        "| QPs by equality first |",
        "|---|---|---|---|---|---|",
    ]
    for label, row in rows.items():
        lines.append(
            f"| {label} | {row['wall']:.3f} | {row['cpu']:.3f} "
            f"({row['range'][0]:.3f}–{row['range'][1]:.3f}) | {row['cpu'] / first['cpu']:.2f} | "
            f"{row['lin']:.3f} / {row['qp']:.3f} | {row['equality_first']:.2f} |"
        )
    return "\n".join(lines)


def breakdown(
    vehicle: str, horizons: tuple[int, ...], rounds: int, steps: int, converged: bool = False
) -> str:
    """Split the ``sqp-rti`` step of ``vehicle`` against N: linearisation, QP, the rest, exponents.

    Each horizon a worker of its own, interleaved (:func:`interleaved`); "Python" is the median
    wall time minus the medians of the C step's two clocks (an estimate: medians do not add).
    ``converged``: the converged mode, whose steps the C step answers only when it converges
    (the rest go through ``solve()``): the share it answered and its iterations are listed.
    """
    options = CONVERGED if converged else RTI
    configs = {
        str(n): {"vehicle": vehicle, "horizon": n, "solver": "sqp-rti", "options": options, "steps": steps}
        for n in horizons
    }
    rows = interleaved(configs, rounds)
    found = [n for n in horizons if str(n) in rows]
    mode = "converged" if converged else "rti"
    lines = [
        f"| {vehicle}, sqp-rti {mode} | "
        + " | ".join(f"N = {n}" for n in found)
        + " | exponent (N = 20..80) |",
        "|" + "---|" * (len(found) + 2),
    ]
    ordered = [rows[str(n)] for n in found]
    columns = {
        "wall ms": [row["wall"] for row in ordered],
        "linearise ms (in C)": [row["lin"] for row in ordered],
        "QP ms (in C)": [row["qp"] for row in ordered],
        "Python ms (wall − C)": [row["wall"] - row["lin"] - row["qp"] for row in ordered],
    }
    for name, times in columns.items():
        cells = " | ".join(f"{t:.3f}" for t in times)
        lines.append(f"| {name} | {cells} | {growth_exponent(found, times):.2f} |")
    shares = " | ".join(f"{row['equality_first']:.2f}" for row in ordered)
    lines.append(f"| QPs answered by equality first | {shares} | |")
    for key, name in (
        ("fast", "steps the C step answered"),
        ("sqp_iterations", "Gauss-Newton iterations (mean, C steps)"),
        ("qp_iterations", "HPIPM iterations of the last QP (median)"),
    ):
        lines.append(f"| {name} | " + " | ".join(f"{row[key]:.2f}" for row in ordered) + " | |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--worker", help=argparse.SUPPRESS)
    parser.add_argument("--against", metavar="SRC", help="the src folder of the baseline checkout")
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--steps", type=int, default=200)
    parser.add_argument(
        "--options", metavar="JSON", help='{"label": options, ...}: sqp-rti closed loops under each'
    )
    parser.add_argument("--vehicle", default="bluerov2", choices=VEHICLES)
    parser.add_argument("--only-vehicle", action="store_true", help="only --vehicle (--against, the table)")
    parser.add_argument("--horizon", type=int, default=20)
    parser.add_argument("--converged", action="store_true", help="--breakdown of the converged mode")
    parser.add_argument("--no-fatrop", action="store_true", help="scaling table without compiled fatrop")
    parser.add_argument("--quick", action="store_true", help="N = 10, 20, 40 and one round")
    parser.add_argument(
        "--build-timeout", type=float, metavar="S", help="leave out a row whose build takes longer"
    )
    parser.add_argument(
        "--breakdown", action="store_true", help="--vehicle's RTI step split against N (10..80)"
    )
    arguments = parser.parse_args(argv)
    if arguments.worker:
        worker(json.loads(arguments.worker))
        return
    global BUILD_TIMEOUT
    BUILD_TIMEOUT = arguments.build_timeout
    print(f"load: {os.getloadavg()}")
    if arguments.breakdown:
        print(breakdown(arguments.vehicle, HORIZONS, arguments.rounds, arguments.steps, arguments.converged))
    elif arguments.options:
        variants = json.loads(arguments.options)
        rounds, steps = arguments.rounds, arguments.steps
        print(compare_options(arguments.vehicle, arguments.horizon, variants, rounds, steps))
    elif arguments.against:
        chosen = (arguments.vehicle,) if arguments.only_vehicle else ("bluerov2", "rexrov")
        print(against(arguments.against, arguments.rounds, arguments.steps, chosen))
    else:
        horizons = HORIZONS[:3] if arguments.quick else HORIZONS
        rounds = 1 if arguments.quick else arguments.rounds
        vehicles = (arguments.vehicle,) if arguments.only_vehicle else VEHICLES
        print(scaling(rounds, arguments.steps, horizons, vehicles, not arguments.no_fatrop))
    print(f"load: {os.getloadavg()}")


if __name__ == "__main__":
    main()
