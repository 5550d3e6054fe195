"""Shared fixtures: small problems built once per session."""

import os

import numpy as np
import pytest

import uuv_ocp as uo

# The swarms compile their cost by default wherever a C compiler exists (~20 s per new problem,
# then cached on disk).  The suite builds dozens of problems, so it runs them on CasADi's
# virtual machine; tests of the compiled path ask for it explicitly, and test_swarm_default
# checks the default itself in a subprocess without this setting.
os.environ.setdefault("UUV_OCP_COMPILED", "0")


@pytest.fixture(scope="session")
def s2_problem():
    """Return the paper's s2 problem on the RexROV, N = 20, dt = 0.1 s, terminal equality."""
    return uo.TrackingProblem(uo.Vehicle.rexrov(), uo.Reference.paper("s2"))


@pytest.fixture(scope="session")
def feasible_start():
    """Return a state slightly off the s2 reference at t0 = 3 s, moving: terminal equality feasible."""
    reference = uo.Reference.paper("s2")
    state = reference.evaluate([3.0])[0]
    state += np.array([0.05, -0.04, 0.02, 0.03, 0.01, -0.01])
    return state, 3.0


needs_compiler = pytest.mark.skipif(
    not any(
        os.path.exists(os.path.join(d, c))
        for d in os.environ.get("PATH", "").split(os.pathsep)
        for c in ("cc", "gcc")
    ),
    reason="no C compiler on this machine",
)
