"""Virtual machine vs compiled C on the s2 problem (N = 20): cost throughput and step times.

* evaluations/s of the swarm fitness for 1, 20 and 100 candidates per call, from Python;
* the SIMD kernel ``cost_batch`` vs CasADi's mapped C (``cost_batch_exact``), zero-copy calls;
* IGWO 20 × 30 NMPC step: Python loop over the VM cost, Python loop over the compiled cost,
  the all-C step (``uuv_ocp_igwo_pcg64``: numpy's PCG64 stream drawn in C) as ``solve`` runs
  it, and the C call alone, with the 288 k uniforms given (evaluations/s *inside* the C step)
  and with them drawn in C;
* exact backends with and without compiled NLP functions (``options={"compiled": True}``:
  CasADi's JIT with the system compiler; ~30 s of compilation per NLP variant, excluded),
  per-step times of the 300-step s2 closed loop from rest.

Run: ``python -m benchmarks.bench_codegen``.
"""

from __future__ import annotations

import os
import tempfile
import time

import numpy as np

import uuv_ocp as uo
from benchmarks.bench_exact import closed_loop_times
from uuv_ocp.codegen import generate_c
from uuv_ocp.solvers.swarm import BufferedFitness, batched_fitness


def _time(function, repeats: int) -> float:
    function()
    start = time.perf_counter()
    for _ in range(repeats):
        function()
    return (time.perf_counter() - start) / repeats


def main() -> dict:
    """Print the tables; return the measurements."""
    os.environ.setdefault("UUV_OCP_CACHE", tempfile.mkdtemp(prefix="uuv_ocp_bench_"))
    reference = uo.Reference.paper("s2")
    problem = uo.TrackingProblem(uo.Vehicle.rexrov(), reference, horizon=20)
    x0 = reference.evaluate([3.0])[0]
    p = problem.parameters(x0, 3.0)
    rng = np.random.default_rng(0)
    results: dict = {"throughput": {}}
    print("\nCode generation, s2, N = 20 (3N = 60 scaled controls)")
    print(f"{'candidates/call':<16}{'VM evals/s':>14}{'compiled evals/s':>18}{'speed-up':>10}")
    for population in (1, 20, 100):
        candidates = rng.uniform(-1, 1, (problem.control_dim, population))
        vm = batched_fitness(problem, population)
        compiled = generate_c(
            problem, os.environ["UUV_OCP_CACHE"], functions=("cost_batch",), population=population
        )["cost_batch"]
        repeats = max(20, 2000 // population)
        vm_rate = population / _time(lambda vm=vm, c=candidates: vm(c, p), repeats)
        c_rate = population / _time(lambda f=compiled, c=candidates: f(c, p), repeats)
        results["throughput"][population] = (vm_rate, c_rate)
        print(f"{population:<16}{vm_rate:>14,.0f}{c_rate:>18,.0f}{c_rate / vm_rate:>10.1f}")

    print("\nPopulation of 20 from Python, zero-copy (Function.buffer), evaluations/s")
    candidates = rng.uniform(-1, 1, (20, problem.control_dim))
    build = generate_c(problem, os.environ["UUV_OCP_CACHE"], functions=("cost_batch",), population=20)
    rates = {}
    for name in ("cost_batch_exact", "cost_batch"):
        call = BufferedFitness(build[name], 20, problem.control_dim, problem.parameter_dim)
        rates[name] = 20 / _time(lambda call=call: call(candidates, p), 2000)
    results["kernel"] = rates
    print(f"  CasADi's mapped C (cost_batch_exact) {rates['cost_batch_exact']:>12,.0f}")
    print(
        f"  SIMD kernel (cost_batch)             {rates['cost_batch']:>12,.0f}"
        f"   ({rates['cost_batch'] / rates['cost_batch_exact']:.1f}x)"
    )

    python_vm = uo.get_solver(problem, "igwo")
    compiled_loop = uo.get_solver(
        problem, "igwo", {"compiled": True, "algorithm_options": {"frame": "origin", "c1": 0.5}}
    )
    compiled_loop.native = None  # force the Python loop over the compiled cost
    all_c = uo.get_solver(problem, "igwo", {"compiled": True})
    steps = {
        "python loop, VM cost": python_vm,
        "python loop, compiled cost": compiled_loop,
        "all-C step (solve, PCG64 in C)": all_c,
    }
    print("\nIGWO 20 x 30 NMPC step at a fixed state (median of 100, ms)")
    timings = {}
    for label, solver in steps.items():
        samples = []
        for seed in range(101):
            start = time.perf_counter()
            solver.solve(p, None, np.random.default_rng(seed))
            samples.append(time.perf_counter() - start)
        timings[label] = float(np.median(samples[1:]))
        print(f"  {label:<30}{1e3 * timings[label]:>8.2f}")
    native = all_c.native
    dim, n, iterations = problem.control_dim, 20, 30
    positions = rng.uniform(-1, 1, (n, dim))
    draws = rng.random((iterations, 8, n, dim))
    a, w = np.linspace(2, 0, iterations), np.linspace(0.9, 0.1, iterations)
    bounds = (np.zeros(dim), -np.ones(dim), np.ones(dim))
    c_only = _time(lambda: native.run(p, *bounds, positions, draws, a, w), 200)
    timings["C call alone"] = c_only
    rate = n * (iterations + 1) / c_only
    print(f"  {'C call, draws given':<30}{1e3 * c_only:>8.2f}   ({rate:,.0f} evaluations/s inside C)")
    generator = np.random.default_rng(1)
    drawing = _time(lambda: native.run(p, *bounds, positions, generator, a, w), 200)
    timings["C call drawing"] = drawing
    print(f"  {'C call, PCG64 draws in C':<30}{1e3 * drawing:>8.2f}")
    results["igwo"] = timings

    print("\nExact backends, 300-step closed loop on s2 from rest (ms per step)")
    print(
        f"  {'solver':<8}{'VM median':>10}{'VM p90':>8}{'compiled median':>17}{'compiled p90':>14}{'fail':>6}"
    )
    exact = {}
    for name in ("ipopt", "fatrop", "sqp"):
        plain = closed_loop_times(name)
        compiled = closed_loop_times(name, options={"compiled": True})
        exact[name] = (plain, compiled)
        print(
            f"  {name:<8}{plain['median_ms']:>10.2f}{plain['p90_ms']:>8.2f}{compiled['median_ms']:>17.2f}"
            f"{compiled['p90_ms']:>14.2f}{compiled['failures']:>6d}"
        )
    results["exact"] = exact
    return results


if __name__ == "__main__":
    main()
