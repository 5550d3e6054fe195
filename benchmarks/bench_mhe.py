"""Per-step time of the moving-horizon estimator (M = 20), full and RTI, VM and compiled, vs the EKF.

One closed loop per vehicle is run with the EKF under a constant current unknown to the
controller (0.5 m/s, `Sensors.auv`); its controls and sensor reports are then replayed to
every estimator in this one process, so all see the same data and their times are measured
together (only the estimator's step is timed, as ``simulate`` times it).

* 3-DOF RexROV on s2 (8 augmented states: x, y, ψ, u, v, r, current 2-D), NMPC sqp-rti N = 10;
* 6-DOF BlueROV2 Heavy on the dive path of ``bench_6dof`` (15 augmented states), NMPC
  sqp-rti N = 20.

Run: ``python -m benchmarks.bench_mhe`` (``--quick``: the 3-DOF vehicle only;
``--flags [--6dof]``: the Gauss–Newton step alone, on CasADi's VM and compiled at -O1, -O2 and
-O3, each build in a fresh temporary folder, so every flag pays its full build time).
"""

from __future__ import annotations

import sys
import tempfile
import time
import timeit

import numpy as np

import uuv_ocp as uo
from benchmarks.bench_6dof import problem as dive_problem
from uuv_ocp.estimation import Measurement
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
            f" {value}" if key == "mode" else " compiled" for key, value in options.items()
        )
        error = float(np.linalg.norm(estimate.current - true_current))
        times = 1e3 * times[1:]
        print(
            f"{label:24s} {built:8.2f} {np.median(times):10.3f} {np.percentile(times, 90):8.3f} {error:17.4f}"
        )


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
