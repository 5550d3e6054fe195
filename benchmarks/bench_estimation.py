"""Closed loops under an unknown ocean current: estimators against the oracle and the naive controller.

On s1..s10 (RexROV, N = 20, dt = 0.1 s) and the BlueROV2 Heavy survey of
``examples/bluerov2_depth.py``, every row runs ``sqp-rti`` for 40 s (s3: its 27 s window) under a
Gauss–Markov current of mean speed 0.5 m/s (direction drawn per seed, speed and direction noise
0.02 /√s, decay 0.01 /s: a stationary spread of ≈ 0.14 m/s), with the sensors of
``uo.Sensors.auv(vehicle)`` (position fix 1 Hz σ 0.5 m, DVL 5 Hz σ 0.02 m/s with 5 % dropouts,
attitude 10 Hz σ 0.5°, gyro, depth), the estimators at their default options, seeds 0..19:

========================  ===========================================================
row                       what the controller is told
========================  ===========================================================
``oracle``                the true state and the true current (no sensors)
``current known``         the EKF's state estimate and the true current
``ekf``, ``ukf``, ``mhe`` that estimator's state and current (offset-free NMPC)
``naive``                 an EKF's state estimate with no current in its model, and no current
``naive (true state)``     the true state (no sensors) and no current
========================  ===========================================================

The table gives, per case, the median over seeds of the tracking RMS (m, the position error
‖p − p_ref‖ over t − t0 ≥ 20 s), each estimator's ratio to ``current known`` (the issue's
goal, ≤ 1.25: the same sensors, the current known) and to ``oracle``; the best estimator's
median and 90th percentile of its per-seed ratios to ``current known`` (paired: the same seed
draws the same current and sensor noise for both); the current-estimation
RMS ‖ĉ − c‖ (m/s) and the position-estimation RMS ‖p̂ − p‖ (m) over the same window; the
medians of the estimator's and the controller's per-step times (ms).

Every run is a checked record (``uuv_ocp.studies.records``: checksummed, written atomically)
in ``--out`` (default ``out/bench_estimation``): an interrupted benchmark resumes where it
stopped, and a damaged record is recomputed.

``--timing``: only the per-step CPU time of each registered estimator (``Estimator.step`` over
200 seeded steps of the sensors' schedule, after 50 warm-up steps; median, ms) on s2 and the
BlueROV2 survey, compiled to C and on CasADi's virtual machine, one process.

``--dompc``: only the estimators against do-mpc's MHE (``pip install -e ".[bench]"``) on one
recorded s2 run (30 s, the oracle's closed loop under a constant 0.5 m/s current), every sensor
at the control rate (do-mpc's MHE takes all outputs every step): position σ 0.5 m, heading
σ 0.5°, body velocities σ 0.02 m/s and yaw rate σ 0.1 °/s; do-mpc's MHE on the same augmented
discrete model (the package's RK4 step), horizon 20, its default objective with the same
weights (``P_x = P0⁻¹``, ``P_v = R⁻¹``, ``P_w = Q⁻¹``), the applied controls given as
measured inputs (with each ``y_k``, the input that moved ``x_k−1`` to ``x_k``); per
estimator the median wall time per step (ms) and the current and position errors over
t ≥ 10 s.

Run: ``python -m benchmarks.bench_estimation [--seeds 20] [--cases s1,s2,...,bluerov2]
[--rows oracle,ekf,...] [--out DIR] [--timing] [--dompc]``.
"""

from __future__ import annotations

import argparse
import math
import re
import time
import warnings
from pathlib import Path

import numpy as np
from tqdm import tqdm

import uuv_ocp as uo
from uuv_ocp.studies.records import read_record, write_record

CASES = tuple(f"s{i}" for i in range(1, 11)) + ("bluerov2",)
ROWS = ("oracle", "current known", "ekf", "ukf", "mhe", "naive", "naive (true state)")
DURATION = 40.0
SETTLED = 20.0  # s after the start: the metrics' window
MEAN_SPEED = 0.5


def case_problem(case: str) -> tuple[uo.TrackingProblem, np.ndarray]:
    """Return the tracking problem of ``case`` and its start state."""
    if case == "bluerov2":
        from benchmarks.bench_rti import _bluerov2_survey

        return _bluerov2_survey()
    problem = uo.TrackingProblem(uo.Vehicle.rexrov(), uo.Reference.paper(case), horizon=20, dt=0.1)
    return problem, problem.reference.initial_state(problem.reference.t_start)


def seeded_current(seed: int) -> uo.Current:
    """Return the Gauss–Markov current of ``seed`` (mean 0.5 m/s, a direction drawn from the seed)."""
    direction = float(np.random.default_rng(1000 + seed).uniform(-math.pi, math.pi))
    return uo.Current(MEAN_SPEED, direction, speed_noise=0.02, direction_noise=0.02, decay=0.01)


def _estimator(problem: uo.TrackingProblem, row: str) -> uo.Estimator | None:
    sensors = uo.Sensors.auv(problem.vehicle)
    if row in ("oracle", "naive (true state)"):
        return None
    if row == "naive":
        return uo.Estimator(
            problem, "ekf", sensors=sensors, options=uo.EstimatorOptions(current_model="none")
        )
    return uo.Estimator(problem, "ekf" if row == "current known" else row, sensors=sensors)


def metrics(run: uo.ClosedLoopResult) -> dict[str, float]:
    """Tracking, current and position-estimation RMS over the window, and the step times (ms)."""
    spatial = 3 if run.states.shape[1] == 12 else 2
    settled = run.t - run.t[0] >= SETTLED
    error = np.linalg.norm(run.states[:, :spatial] - run.reference[:, :spatial], axis=1)
    result = {
        "tracking_rms": float(np.sqrt(np.mean(error[settled] ** 2))),
        "controller_ms": 1e3 * float(np.median(run.solve_times)),
        "failures": float(run.failures),
    }
    estimates = run.estimates
    if estimates is not None:
        window = settled[: estimates.states.shape[0]]
        position = estimates.states[:, :spatial] - run.states[: window.size, :spatial]
        result["position_rms"] = float(np.sqrt(np.mean(np.sum(position[window] ** 2, axis=1))))
        result["estimator_ms"] = 1e3 * float(np.median(estimates.times))
        if estimates.currents.shape[1]:
            true = run.currents[: window.size, : estimates.currents.shape[1]]
            current = estimates.currents - true
            result["current_rms"] = float(np.sqrt(np.mean(np.sum(current[window] ** 2, axis=1))))
    return result


def run_case(case: str, rows: tuple[str, ...], seeds: int, out: Path, bar: tqdm) -> dict[str, list[dict]]:
    """Run (or read back) every row and seed of ``case``; per row, the metrics of each seed."""
    problem, start = case_problem(case)
    controller = uo.NMPC(problem, "sqp-rti", seed=1)
    results: dict[str, list[dict]] = {}
    for row in rows:
        if row == "mhe" and "mhe" not in uo.available_estimators():
            bar.update(seeds)
            continue
        estimator = _estimator(problem, row)
        results[row] = []
        for seed in range(seeds):
            config = {"bench": "estimation", "case": case, "row": row, "seed": seed, "duration": DURATION}
            path = out / f"{case}-{re.sub('[^a-z]+', '_', row).strip('_')}-{seed:02d}.npz"
            saved = read_record(path, config)
            if saved is None:
                with warnings.catch_warnings():  # s3's window is shorter than the run: said above
                    warnings.simplefilter("ignore", RuntimeWarning)
                    run = uo.simulate(
                        controller,
                        start,
                        DURATION,
                        current=seeded_current(seed),
                        current_known=row in ("oracle", "current known"),
                        estimator=estimator,
                        seed=seed,
                    )
                write_record(path, run, config)
            else:
                run = saved[0]
            results[row].append(metrics(run))
            bar.update(1)
    return results


def timing(steps: int = 200) -> str:
    """Per-step CPU time (ms) of each registered estimator, compiled and on the VM (module doc)."""
    lines = ["| case | estimator | compiled ms | virtual machine ms |", "|---|---|---|---|"]
    for case in ("s2", "bluerov2"):
        problem, start = case_problem(case)
        sensors = uo.Sensors.auv(problem.vehicle)
        rng = np.random.default_rng(1)
        measurements = [sensors.measure(k, problem.dt, start, rng) for k in range(steps + 50)]
        control = np.zeros(problem.spec().control_size)
        for name in uo.available_estimators():
            cells = []
            for compiled in (True, False):
                options = uo.EstimatorOptions(compiled=compiled)
                estimator = uo.Estimator(problem, name, sensors=sensors, options=options)
                estimator.reset(start)
                times = []
                for k, measurement in enumerate(measurements):
                    begin = time.process_time()
                    estimator.step(control, measurement)
                    if k >= 50:
                        times.append(time.process_time() - begin)
                cells.append(
                    f"{1e3 * float(np.median(times)):.3f}" if estimator.compiled or not compiled else "—"
                )
            lines.append(f"| {case} | {name} | {cells[0]} | {cells[1]} |")
    return "\n".join(lines)


def _single_rate_sensors() -> uo.Sensors:
    """Every output at 10 Hz (the control rate), no dropouts: what do-mpc's MHE can take."""
    return uo.Sensors(
        [
            uo.Sensor.of_states("position", [0, 1], 6, 10.0, (0.5, 0.5)),
            uo.Sensor.of_states("heading", [2], 6, 10.0, (math.radians(0.5),), angular=(True,)),
            uo.Sensor.of_states("velocity", [3, 4, 5], 6, 10.0, (0.02, 0.02, math.radians(0.1))),
        ]
    )


def _dompc_mhe(estimator: uo.Estimator, start: np.ndarray) -> object:
    """do-mpc's MHE on ``estimator``'s augmented model, weights and prior (module doc)."""
    import casadi as ca
    import do_mpc

    m = estimator.model
    model = do_mpc.model.Model("discrete")
    state = model.set_variable("_x", "xa", shape=(m.size, 1))
    control = model.set_variable("_u", "u", shape=(m.nu, 1))
    step = ca.Function("f", [m.xa, m.u, m.ps, m.pg], [m.f])
    model.set_rhs("xa", step(state, control, ca.DM(m.p_stage), ca.DM(m.p_global)), process_noise=True)
    model.set_meas("y", ca.Function("h", [m.xa], [m.h])(state), meas_noise=True)
    model.set_meas("u_meas", control, meas_noise=False)
    model.setup()
    mhe = do_mpc.estimator.MHE(model)
    mhe.settings.n_horizon = 20
    mhe.settings.t_step = m.dt
    mhe.settings.meas_from_data = True
    mhe.settings.supress_ipopt_output()
    mhe.set_default_objective(np.linalg.inv(m.P0), np.diag(1.0 / estimator.R), P_w=np.linalg.inv(m.Q))
    mhe.setup()
    mhe.x0 = np.concatenate([start, np.zeros(m.size - m.nx)])
    mhe.set_initial_guess()
    return mhe


def dompc_comparison() -> str:
    """Return the table of the package's estimators against do-mpc's MHE on one recorded run (module doc)."""
    problem, start = case_problem("s2")
    sensors = _single_rate_sensors()
    run = uo.simulate(uo.NMPC(problem, "sqp-rti"), start, 30.0, current=uo.Current(0.5, 1.0), seed=1)
    rng = np.random.default_rng(7)
    measurements = [sensors.measure(k, problem.dt, run.states[k], rng) for k in range(run.controls.shape[0])]
    settled = run.t[: len(measurements)] - run.t[0] >= 10.0
    lines = ["| estimator | ms per step | current RMS m/s | position RMS m |", "|---|---|---|---|"]
    rows: list[tuple[str, object]] = [(name, None) for name in uo.available_estimators()]
    rows.append(("do-mpc MHE (IPOPT, M = 20)", "dompc"))
    for label, kind in rows:
        estimator = uo.Estimator(problem, "ekf" if kind else label, sensors=sensors)
        estimator.reset(start)
        mhe = _dompc_mhe(estimator, start) if kind else None
        times, states = [], []
        for k, measurement in enumerate(measurements):
            begin = time.perf_counter()
            if mhe is not None:
                # y_k paired with the input that moved x_k-1 to x_k (pairing it with the input
                # applied at k gave a current error of 0.28 m/s instead of 0.02)
                applied = run.controls[k - 1] if k else np.zeros(problem.spec().control_size)
                y = np.concatenate([measurement.values, applied])
                states.append(np.asarray(mhe.make_step(y)).ravel())  # type: ignore[attr-defined]
            else:
                applied = run.controls[k - 1] if k else None
                estimate = estimator.correct(measurement) if k == 0 else estimator.step(applied, measurement)
                states.append(estimate.augmented)
            times.append(time.perf_counter() - begin)
        found = np.array(states)
        current = np.linalg.norm(found[:, 6:8] - run.currents[: len(found)], axis=1)[settled]
        position = np.linalg.norm(found[:, :2] - run.states[: len(found), :2], axis=1)[settled]
        lines.append(
            f"| {label} | {1e3 * float(np.median(times)):.3f} | "
            f"{float(np.sqrt(np.mean(current**2))):.4f} | {float(np.sqrt(np.mean(position**2))):.4f} |"
        )
    return "\n".join(lines)


def _median(values: list[dict], key: str) -> float:
    found = [v[key] for v in values if key in v]
    return float(np.median(found)) if found else math.nan


def _paired(rows: dict[str, list[dict]], row: str, base: str) -> np.ndarray:
    """Per-seed ratios ``row / base`` of the tracking RMS (the same seed: the same current and noise)."""
    ours = [v["tracking_rms"] for v in rows.get(row, [])]
    theirs = [v["tracking_rms"] for v in rows.get(base, [])]
    return (
        np.asarray(ours) / np.asarray(theirs) if ours and len(ours) == len(theirs) else np.full(1, math.nan)
    )


def table(results: dict[str, dict[str, list[dict]]]) -> str:
    """Format the markdown table of :func:`run_case`'s results."""
    estimators = [r for r in ("ekf", "ukf", "mhe") if any(r in rows for rows in results.values())]
    head = ["case", "oracle RMS m", "current known RMS m"]
    head += [f"{r} RMS m (× known, × oracle)" for r in estimators]
    head += ["naive RMS m (× known)", "naive (true state) RMS m (× oracle)"]
    head += [f"{r} current RMS m/s" for r in estimators] + ["ekf position RMS m"]
    head += [f"{r} ms" for r in estimators] + ["controller ms"]
    head += ["best per-seed × known: median (p90)"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for case, rows in results.items():
        oracle = _median(rows.get("oracle", []), "tracking_rms")
        known = _median(rows.get("current known", []), "tracking_rms")
        cells = [case, f"{oracle:.3g}", f"{known:.3g}"]
        for r in estimators:
            rms = _median(rows.get(r, []), "tracking_rms")
            cells.append(f"{rms:.3g} ({rms / known:.2f}, {rms / oracle:.0f})")
        naive = _median(rows.get("naive", []), "tracking_rms")
        cells.append(f"{naive:.3g} ({naive / known:.2f})")
        blind = _median(rows.get("naive (true state)", []), "tracking_rms")
        cells.append(f"{blind:.3g} ({blind / oracle:.0f})")
        cells += [f"{_median(rows.get(r, []), 'current_rms'):.3f}" for r in estimators]
        cells.append(f"{_median(rows.get('ekf', []), 'position_rms'):.3f}")
        cells += [f"{_median(rows.get(r, []), 'estimator_ms'):.3f}" for r in estimators]
        cells.append(f"{_median(rows.get('ekf', []), 'controller_ms'):.3f}")
        paired = {r: _paired(rows, r, "current known") for r in estimators}
        best = min(paired, key=lambda r: float(np.median(paired[r]))) if paired else None
        cells.append(
            f"{best} {np.median(paired[best]):.2f} ({np.percentile(paired[best], 90):.2f})" if best else "—"
        )
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    """Run the benchmark (resuming from ``--out``) and print its table."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=20)
    parser.add_argument("--cases", default=",".join(CASES))
    parser.add_argument("--rows", default=",".join(ROWS))
    parser.add_argument("--out", type=Path, default=Path("out/bench_estimation"))
    parser.add_argument("--timing", action="store_true", help="only the estimators' per-step time")
    parser.add_argument("--dompc", action="store_true", help="only the estimators against do-mpc's MHE")
    arguments = parser.parse_args(argv)
    if arguments.timing:
        print(timing())
        return 0
    if arguments.dompc:
        print(dompc_comparison())
        return 0
    cases = tuple(arguments.cases.split(","))
    rows = tuple(arguments.rows.split(","))
    for name, chosen, allowed in (("--cases", cases, CASES), ("--rows", rows, ROWS)):
        unknown = sorted(set(chosen) - set(allowed))
        if unknown:
            parser.error(f"{name} must be among {list(allowed)}, got {unknown}")
    if arguments.seeds < 1:
        parser.error(f"--seeds must be >= 1, got {arguments.seeds}")
    arguments.out.mkdir(parents=True, exist_ok=True)
    results = {}
    with tqdm(total=len(cases) * len(rows) * arguments.seeds, desc="closed loops") as bar:
        for case in cases:
            results[case] = run_case(case, rows, arguments.seeds, arguments.out, bar)
    print(table(results))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
