"""Shared fixtures: small problems built once per session."""

import os
from pathlib import Path

import numpy as np
import pytest

import uuv_ocp as uo

# The swarms compile their cost by default wherever a C compiler exists (~20 s per new problem,
# then cached on disk).  The suite builds dozens of problems, so it runs them on CasADi's
# virtual machine; tests of the compiled path ask for it explicitly, and test_swarm_default
# checks the default itself in a subprocess without this setting.
os.environ.setdefault("UUV_OCP_COMPILED", "0")

# The build cache of this checkout (issue 31): the default ~/.cache/uuv_ocp is shared by every
# checkout and venv of the machine, so what another one built there (above all a native HPIPM,
# which "auto" then links into every C step) changed this suite's results.  A folder inside the
# checkout keeps its compiled C between runs (a cold cache recompiles every C step: see
# docs/codegen.md for the measured cost); UUV_OCP_TEST_CACHE chooses another folder.  The C step
# links the wheel's HPIPM unless the run asks otherwise (UUV_OCP_HPIPM=native make test), so a
# native build made by tests/native/test_hpipm.py does not change the tests that run after it.
os.environ["UUV_OCP_CACHE"] = os.environ.get("UUV_OCP_TEST_CACHE", "").strip() or str(
    Path(__file__).resolve().parent.parent / "build" / "test-cache"
)
os.environ.setdefault("UUV_OCP_HPIPM", "wheel")
# Nor does the suite build the native HPIPM on a C step's first need (minutes; CI has 30): the
# tests of that path (tests/native/test_hpipm.py) set the policy themselves with a stand-in build.
os.environ.setdefault("UUV_OCP_HPIPM_BUILD", "never")


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
