"""The examples run as scripts at small sizes."""

import importlib.util
from pathlib import Path

import numpy as np

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"


def load(name):
    spec = importlib.util.spec_from_file_location(name, EXAMPLES / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_compare_solvers_example(tmp_path):
    rows = load("compare_solvers").main(
        solvers=("ipopt", "sqp", "igwo", "gwo", "igwo+ipopt"),
        horizon=8,
        swarm_options={"population": 8, "iterations": 5},
        out=tmp_path,
    )
    by_name = {row.solver: row for row in rows}
    assert by_name["ipopt"].cost == by_name["igwo+ipopt"].cost or np.isclose(
        by_name["ipopt"].cost, by_name["igwo+ipopt"].cost, rtol=1e-6
    )
    assert by_name["igwo"].ratio >= 1.0 and by_name["ipopt"].ratio <= 1.0 + 1e-6
    assert (tmp_path / "compare_convergence.png").stat().st_size > 1000


def test_readme_ten_line_example_runs():
    import re

    readme = (EXAMPLES.parent / "README.md").read_text()
    code = re.search(r"## In ten lines\n\n```python\n(.*?)```", readme, re.S).group(1)
    namespace = {}
    exec(compile(code.replace("duration=10.0", "duration=1.0"), "README.md", "exec"), namespace)
    assert namespace["run"].failures == 0
    assert namespace["res"].controls.shape == (20, 3)
