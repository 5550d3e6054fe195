"""What compiling fatrop's NLP costs: generated C size, compiler time per flag, BlueROV2 survey.

For each horizon the fatrop NLP (the hard variant) is built on CasADi's virtual machine, the
functions the plugin evaluates are generated into one C file (as
:func:`uuv_ocp.native.runtime.compiled_nlpsol` does) and compiled once per optimisation level,
one compile after the other; printed: C size, CasADi instructions, compiler wall and CPU time
(children's user + system), and the load.

Run: ``python -m benchmarks.bench_fatrop_build --horizons 20 --levels=-O0,-O1`` (comma separated,
after ``=``: argparse reads a bare ``-O0`` as an option); ``--unrolled``: the unrolled SX NLP that
``compiled=True`` built before the outlining (issue 29), for the before/after comparison.
"""

from __future__ import annotations

import argparse
import os
import resource
import subprocess
import tempfile
import time
from pathlib import Path

import casadi as ca


def nlp_functions(horizon: int, outlined: bool = True) -> list[ca.Function]:
    """Return the functions fatrop evaluates on the BlueROV2 survey's hard NLP at ``horizon``.

    ``outlined``: the NLP ``compiled=True`` builds (one Function per stage structure, called per
    stage: :mod:`uuv_ocp.transcription.outline`); ``False``: the unrolled SX NLP (before).
    """
    import uuv_ocp as uo
    from benchmarks.bench_rti import _bluerov2_survey
    from uuv_ocp.native import runtime
    from uuv_ocp.transcription.outline import outline

    captured: list[ca.Function] = []

    def capture(
        name: str, plugin: str, nlp: dict, options: dict, stages: list | None = None, rows: list | None = None
    ) -> tuple[ca.Function, None]:
        if outlined and stages is not None:
            nlp, options = outline(nlp, stages, rows).nlp, {**options, "expand": False}
        plain = ca.nlpsol(name, plugin, nlp, options)
        captured.extend(plain.get_function(entry) for entry in plain.get_function())
        captured.append(plain.oracle())
        return plain, None

    original = runtime.compiled_nlpsol
    import uuv_ocp.solvers.nlp as nlp_module

    nlp_module.compiled_nlpsol = capture  # type: ignore[assignment]
    try:
        problem, _ = _bluerov2_survey(horizon)
        uo.solvers.new_solver(problem, "fatrop", {"compiled": True})._solver("hard")
    finally:
        nlp_module.compiled_nlpsol = original
    return captured


def children_cpu() -> float:
    """CPU seconds (user + system) of this process's finished children."""
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--horizons", type=int, nargs="+", default=[20, 40, 80])
    parser.add_argument("--levels", default="-O0,-O1,-O2", help="comma-separated, e.g. --levels=-O0,-O1")
    parser.add_argument("--unrolled", action="store_true", help="the unrolled SX NLP (before outlining)")
    arguments = parser.parse_args(argv)
    print(f"load: {os.getloadavg()}, {'unrolled' if arguments.unrolled else 'outlined'}", flush=True)
    with tempfile.TemporaryDirectory() as folder:
        for horizon in arguments.horizons:
            functions = nlp_functions(horizon, outlined=not arguments.unrolled)
            instructions = sum(f.n_instructions() for f in functions)
            begin = time.perf_counter()
            generator = ca.CodeGenerator(f"nlp{horizon}.c")
            for function in functions:
                generator.add(function)
            generator.generate(folder + os.sep)
            source = Path(folder) / f"nlp{horizon}.c"
            generated = time.perf_counter() - begin
            print(
                f"N = {horizon}: {instructions} instructions, C {source.stat().st_size / 1e6:.1f} MB, "
                f"generated in {generated:.1f} s",
                flush=True,
            )
            for level in arguments.levels.split(","):
                library = Path(folder) / f"nlp{horizon}{level}.so"
                cpu, begin = children_cpu(), time.perf_counter()
                subprocess.run(
                    ["gcc", level, "-fPIC", "-shared", str(source), "-o", str(library), "-lm"], check=True
                )
                print(
                    f"  {level}: {time.perf_counter() - begin:.0f} s wall, {children_cpu() - cpu:.0f} s CPU, "
                    f"library {library.stat().st_size / 1e6:.1f} MB, load {os.getloadavg()}",
                    flush=True,
                )


if __name__ == "__main__":
    main()
