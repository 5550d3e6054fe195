"""The examples run as scripts at small sizes."""

import importlib.util
from pathlib import Path

import numpy as np
import pytest

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"


def load(name):
    spec = importlib.util.spec_from_file_location(name, EXAMPLES / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_compare_solvers_example(tmp_path, capsys):
    solvers = ("ipopt", "sqp", "igwo", "gwo", "igwo+ipopt")
    rows = load("compare_solvers").main(
        solvers=solvers,
        horizon=8,
        swarm_options={"population": 8, "iterations": 5},
        out=tmp_path,
    )
    printed = capsys.readouterr().out
    assert [row.solver for row in rows] == list(solvers)
    table = printed.splitlines()
    for name in solvers:  # the printed table has a line for every solver
        assert any(line.split()[:1] == [name] for line in table), name
    by_name = {row.solver: row for row in rows}
    exact = by_name["ipopt"].cost
    # three routes to the optimum (interior point, SQP, swarm + interior point) agree
    for name in ("sqp", "igwo+ipopt"):
        assert by_name[name].cost == pytest.approx(exact, rel=1e-6), name
    assert all(by_name[name].success for name in ("ipopt", "sqp", "igwo+ipopt"))
    for name in ("igwo", "gwo"):
        row = by_name[name]
        assert row.success and np.isfinite(row.cost) and np.isfinite(row.max_violation)
        # 48 evaluations cannot reach the optimum: strictly worse, and the ratio says by how much
        assert row.cost > exact * (1 + 1e-6)
        assert row.ratio == pytest.approx(row.cost / exact, rel=1e-12)
        assert row.evaluations == 8 * 6 and row.history.shape == (6,) and np.all(np.diff(row.history) <= 0)
    assert min(row.cost for row in rows) == pytest.approx(exact, rel=1e-6)  # the best is the optimum
    assert (tmp_path / "compare_convergence.png").stat().st_size > 1000


def test_readme_ten_line_example_runs():
    import re

    readme = (EXAMPLES.parent / "README.md").read_text()
    code = re.search(r"## In ten lines\n\n```python\n(.*?)```", readme, re.S).group(1)
    namespace = {}
    exec(compile(code.replace("duration=10.0", "duration=1.0"), "README.md", "exec"), namespace)
    assert namespace["run"].failures == 0
    assert namespace["res"].controls.shape == (20, 3)
