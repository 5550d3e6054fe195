"""Per-step time of the moving-horizon estimator (M = 20), full and RTI, VM and compiled, vs the EKF.

One closed loop per vehicle is run with the EKF under a constant current unknown to the
controller (0.5 m/s, `Sensors.auv`); its controls and sensor reports are then replayed to
every estimator in this one process, so all see the same data and their times are measured
together (only the estimator's step is timed, as ``simulate`` times it).

* 3-DOF RexROV on s2 (8 augmented states: x, y, ψ, u, v, r, current 2-D), NMPC sqp-rti N = 10;
* 6-DOF BlueROV2 Heavy on the dive path of ``bench_6dof`` (15 augmented states), NMPC
  sqp-rti N = 20.

The last row is the reason the MHE has its own Gauss–Newton solve instead of the package's NLP
backends: ipopt (through ``nlpsol``, built once with the window's data as parameters) on the
full MHE's window at each full-window step, started 1 cm off its minimiser; the time per solve
and the largest distance between the two minimisers.

Run: ``python -m benchmarks.bench_mhe`` (``--quick``: the 3-DOF vehicle only;
``--flags [--6dof]``: the Gauss–Newton step alone, on CasADi's VM and compiled at -O1, -O2 and
-O3, each build in a fresh temporary folder, so every flag pays its full build time).
"""

from __future__ import annotations

import sys
import tempfile
import time
import timeit

import casadi as ca
import numpy as np

import uuv_ocp as uo
from benchmarks.bench_6dof import problem as dive_problem
from uuv_ocp.estimation import Measurement, MovingHorizonEstimator
from uuv_ocp.native.buffered import BufferedFunction
from uuv_ocp.native.compile import compile_functions

VARIANTS = (
    ("ekf", {"compiled": False}),  # the VM, as the MHE rows without compiled=True
    ("mhe", {"mode": "rti"}),
    ("mhe", {"mode": "full"}),
    ("mhe", {"mode": "rti", "compiled": True}),
    ("mhe", {"mode": "full", "compiled": True}),
)


def replay(run: uo.ClosedLoopResult, sensors: uo.Sensors) -> list[Measurement]:
    """Return the sensor reports of a run as Measurements (a sensor reported where its rows are finite)."""
    values = run.measurements.values
    offsets = np.concatenate([[0], np.cumsum(sensors.sizes)])
    reports = []
    for k in range(values.shape[0]):
        reported = tuple(
            j for j in range(len(sensors)) if np.all(np.isfinite(values[k, offsets[j] : offsets[j + 1]]))
        )
        rows = sensors.rows(reported)
        reports.append(Measurement(k, reported, values[k, rows]))
    return reports


class IpoptWindow:
    """The full MHE's window problem written out for ipopt, its data as parameters (built once).

    The same cost as ``window_by_ipopt`` of ``tests/estimation/test_mhe.py`` (arrival cost,
    masked and wrapped measurement residuals, process noise), for a full window of M intervals.
    """

    def __init__(self, mhe: MovingHorizonEstimator) -> None:
        m, M = mhe.model, mhe.horizon
        f = ca.Function("f", m.inputs, [m.f])
        h = ca.Function("h", [m.xa], [m.h])
        rows = mhe.R.size
        X = ca.SX.sym("X", m.size, M + 1)
        prior, Pinv = ca.SX.sym("prior", m.size), ca.SX.sym("Pinv", m.size, m.size)
        Z, W, U = ca.SX.sym("Z", rows, M + 1), ca.SX.sym("W", rows, M + 1), ca.SX.sym("U", m.nu, M)
        sqrt_Rinv = np.sqrt(1.0 / mhe.R)
        deviation = X[:, 0] - prior
        cost = ca.bilin(Pinv, deviation, deviation)
        Qinv = ca.DM(np.linalg.inv(m.Q))
        for i in range(M + 1):
            y = Z[:, i] - h(X[:, i])
            y = ca.vertcat(
                *[ca.atan2(ca.sin(y[r]), ca.cos(y[r])) if mhe.angular[r] else y[r] for r in range(rows)]
            )
            cost += ca.sumsqr(W[:, i] * y * sqrt_Rinv)
            if i < M:
                w = X[:, i + 1] - f(X[:, i], U[:, i], m.p_stage, m.p_global)
                cost += ca.bilin(Qinv, w, w)
        data = ca.vertcat(prior, ca.vec(Pinv), ca.vec(Z), ca.vec(W), ca.vec(U))
        options = {"ipopt.print_level": 0, "print_time": False, "ipopt.tol": 1e-10}
        self.solver = ca.nlpsol("window", "ipopt", {"x": ca.vec(X), "p": data, "f": cost}, options)
        self.shape = (m.size, M + 1)

    def solve(self, mhe: MovingHorizonEstimator, start: np.ndarray) -> np.ndarray:
        """Solve the window ``mhe`` holds now from ``start``; return the minimiser (columns = nodes)."""
        Z = np.nan_to_num(mhe._Z)  # unreported rows are masked by W
        data = np.concatenate(
            [mhe._prior, mhe._prior_Pinv.ravel("F"), Z.ravel("F"), mhe._W.ravel("F"), mhe._U.ravel("F")]
        )
        solution = self.solver(x0=start.ravel("F"), p=data)
        if not self.solver.stats()["success"]:
            raise RuntimeError(f"ipopt on the window: {self.solver.stats()['return_status']}")
        return np.asarray(solution["x"]).reshape(self.shape, order="F")


def ipopt_row(
    estimator: MovingHorizonEstimator, run: uo.ClosedLoopResult, reports: list[Measurement], x0: np.ndarray
) -> str:
    """Time ipopt on the full MHE's window at every full-window step of the replay (one row)."""
    mhe = estimator
    window = IpoptWindow(mhe)
    rng = np.random.default_rng(0)
    times, gaps = [], []
    estimator.reset(x0)
    for k, measurement in enumerate(reports):
        if k == 0:
            estimator.correct(measurement)
        else:
            estimator.step(run.controls[k - 1], measurement)
        if mhe._length < mhe.horizon:
            continue
        minimiser = mhe.window[1]
        start = minimiser + rng.normal(0.0, 0.01, minimiser.shape)
        began = time.perf_counter()
        solution = window.solve(mhe, start)
        times.append(time.perf_counter() - began)
        gaps.append(np.max(np.abs(solution - minimiser)))
    ms = 1e3 * np.asarray(times)
    return (
        f"{'mhe window by ipopt':24s} {'':8s} {np.median(ms):10.3f} {np.percentile(ms, 90):8.3f}"
        f"   max |x_ipopt − x_mhe| {max(gaps):.1e} over {len(times)} windows"
    )


def bench(name: str, problem: uo.TrackingProblem, controller: str, duration: float) -> None:
    """Print median / p90 ms per estimator step and the current error at the end, per variant."""
    vehicle = problem.vehicle
    sensors = uo.Sensors.auv(vehicle)
    x0 = problem.reference.initial_state(0.0)
    current = uo.Current(0.5, 1.0)
    ekf = uo.Estimator(problem, "ekf", sensors=sensors)
    run = uo.simulate(
        uo.NMPC(problem, controller), x0=x0, duration=duration, current=current, estimator=ekf, seed=1
    )
    reports = replay(run, sensors)
    true_current = run.currents[-1]
    steps = len(reports)
    print(
        f"\n{name}: {steps} steps, M = 20, controller {controller}, "
        f"NMPC median {1e3 * np.median(run.solve_times):.3f} ms"
    )
    header = f"{'estimator':24s} {'build s':>8s} {'median ms':>10s} {'p90 ms':>8s}"
    print(f"{header} {'|c − c_true| m/s':>17s}")
    for method, options in VARIANTS:
        start = time.perf_counter()
        estimator = uo.Estimator(problem, method, sensors=sensors, options=uo.EstimatorOptions(**options))
        built = time.perf_counter() - start
        estimator.reset(x0)
        times = np.zeros(steps)
        for k, measurement in enumerate(reports):
            start = time.perf_counter()
            estimate = (
                estimator.correct(measurement) if k == 0 else estimator.step(run.controls[k - 1], measurement)
            )
            times[k] = time.perf_counter() - start
        label = method + "".join(
            f" {value}" if key == "mode" else (" compiled" if value else " (VM)")
            for key, value in options.items()
        )
        error = float(np.linalg.norm(estimate.current - true_current))
        times = 1e3 * times[1:]
        print(
            f"{label:24s} {built:8.2f} {np.median(times):10.3f} {np.percentile(times, 90):8.3f} {error:17.4f}"
        )
        if options == {"mode": "full"}:
            full = estimator
    print(ipopt_row(full, run, reports, x0))


def flags(six_dof: bool = False) -> None:
    """Print µs per call of the Gauss–Newton step (fixed inputs) and its build time, per flag."""
    if six_dof:
        problem = dive_problem()
    else:
        problem = uo.TrackingProblem(uo.Vehicle.rexrov(), uo.Reference.paper("s2"), horizon=10)
    sensors = uo.Sensors.auv(problem.vehicle)
    options = uo.EstimatorOptions(horizon=20, mode="rti")
    step = uo.Estimator(problem, "mhe", sensors=sensors, options=options)._gauss_newton
    function = step.function
    rng = np.random.default_rng(0)
    inputs = [rng.random(function.size_in(i)) for i in range(function.n_in())]
    print(f"\nGauss–Newton step, {function.n_instructions()} instructions")
    print(f"VM   {1e6 * timeit.timeit(lambda: step(*inputs), number=300) / 300:8.1f} µs")
    for flag in ("-O1", "-O2", "-O3"):
        with tempfile.TemporaryDirectory() as folder:
            start = time.perf_counter()
            library = compile_functions(
                [function], folder, name="bench_mhe", flags=(flag, "-fPIC", "-shared")
            )
            built = time.perf_counter() - start
            compiled = BufferedFunction(library.functions[function.name()])
            each = timeit.timeit(lambda call=compiled: call(*inputs), number=2000) / 2000
        print(f"{flag}  {1e6 * each:8.1f} µs, built in {built:.1f} s")


def main(quick: bool = False) -> None:
    """Run the 3-DOF RexROV and (unless ``quick``) the 6-DOF BlueROV2 benchmark."""
    rexrov = uo.TrackingProblem(uo.Vehicle.rexrov(), uo.Reference.paper("s2"), horizon=10)
    bench("3-DOF RexROV, s2", rexrov, "sqp-rti", 30.0)
    if not quick:
        bench("6-DOF BlueROV2 Heavy, dive", dive_problem(), "sqp-rti", 30.0)


if __name__ == "__main__":
    if "--flags" in sys.argv:
        flags(six_dof="--6dof" in sys.argv)
    else:
        main(quick="--quick" in sys.argv)
