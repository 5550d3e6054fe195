"""Importing the package has no side effects: no matplotlib, no files written."""

import os
import subprocess
import sys

import pytest


def _fresh_import(statement, cwd):
    """Run ``statement`` in a new interpreter started in ``cwd``, with home and caches in ``cwd``."""
    home = cwd / "home"
    env = dict(os.environ)
    env.update(
        HOME=str(home),
        XDG_CACHE_HOME=str(home / ".cache"),
        XDG_CONFIG_HOME=str(home / ".config"),
        MPLCONFIGDIR=str(home / ".matplotlib"),
        UUV_OCP_CACHE=str(home / "uuv_ocp_cache"),
    )
    completed = subprocess.run(
        [sys.executable, "-c", statement],
        cwd=cwd,
        env=env,
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )
    assert completed.returncode == 0, completed.stderr
    return completed.stdout.strip()


@pytest.mark.parametrize("module", ["uuv_ocp", "uuv_ocp.cli"])
def test_import_loads_no_matplotlib_and_writes_nothing(tmp_path, module):
    statement = f"import {module}, sys; print('matplotlib' in sys.modules)"
    assert _fresh_import(statement, tmp_path) == "False"
    assert sorted(path.relative_to(tmp_path) for path in tmp_path.rglob("*")) == []


def test_figures_need_neither_pyplot_nor_a_backend_choice(tmp_path):
    statement = """
import sys
import numpy as np
from uuv_ocp.control.simulation import ClosedLoopResult
from uuv_ocp.plotting import error_figure, save_figure, xoy_figure

n = 5
run = ClosedLoopResult(
    t=np.linspace(0.0, 0.5, n + 1),
    states=np.zeros((n + 1, 6)),
    controls=np.zeros((n, 3)),
    reference=np.ones((n + 1, 6)),
    solve_times=np.zeros(n),
    iterations=np.zeros(n, dtype=int),
    fallback_steps=np.zeros(n, dtype=bool),
    relaxed_steps=np.zeros(n, dtype=bool),
    currents=np.zeros((n + 1, 2)),
    statuses=("ok",) * n,
    solver="test",
)
for name, figure in (("xoy", xoy_figure(run)), ("errors", error_figure(run, "e"))):
    assert save_figure(figure, f"figures/{name}.png").stat().st_size > 1000
print("matplotlib.pyplot" in sys.modules)
"""
    assert _fresh_import(statement, tmp_path) == "False"
    assert sorted(path.name for path in (tmp_path / "figures").iterdir()) == ["errors.png", "xoy.png"]
