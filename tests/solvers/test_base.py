"""The Backend protocol (uuv_ocp.solvers.base), checked by the registry at registration or first build."""

import numpy as np
import pytest

import uuv_ocp as uo
from uuv_ocp.solvers import REGISTRY, new_solver
from uuv_ocp.solvers.base import Backend, TimeLimited, check_backend, takes_time_limit


@pytest.fixture(scope="module")
def tiny():
    return uo.TrackingProblem(uo.Vehicle.rexrov(), uo.Reference.paper("s2"), horizon=3)


@pytest.fixture
def registered():
    names = []
    yield names
    for name in names:
        REGISTRY._factories.pop(name, None)


def test_a_class_without_solve_is_refused_at_registration(registered):
    class NoSolve:
        name = "no-solve"

        def __init__(self, problem, options=None):
            pass

    registered.append("no-solve")
    with pytest.raises(TypeError, match=r"'no-solve'.*NoSolve has no solve"):
        uo.register_solver("no-solve", NoSolve)
    assert "no-solve" not in REGISTRY._factories


def test_a_solve_without_warm_start_and_rng_is_refused_at_registration(registered):
    class Narrow:
        name = "narrow"

        def __init__(self, problem, options=None):
            pass

        def solve(self, p):
            raise AssertionError("never called")

    registered.append("narrow")
    with pytest.raises(TypeError, match=r"'narrow'.*\(p, warm_start, rng\)"):
        uo.register_solver("narrow", Narrow)


def test_a_declared_time_limit_must_be_taken(registered):
    class Claims:
        name = "claims"
        time_limited = True

        def __init__(self, problem, options=None):
            pass

        def solve(self, p, warm_start=None, rng=None):
            raise AssertionError("never called")

    registered.append("claims")
    with pytest.raises(TypeError, match=r"'claims'.*time_limited = True.*no time_limit"):
        uo.register_solver("claims", Claims)


def test_a_factory_function_is_checked_at_its_first_build(tiny, registered):
    class Nameless:
        def solve(self, p, warm_start=None, rng=None):
            raise AssertionError("never called")

    registered.append("nameless")
    uo.register_solver("nameless", lambda problem, options: Nameless())  # not readable before a build
    with pytest.raises(TypeError, match=r"'nameless'.*Nameless has no name"):
        new_solver(tiny, "nameless")


BASE = [n for n in uo.available_solvers() if REGISTRY.kind(n) in ("exact", "swarm")]


@pytest.mark.parametrize("name", BASE)
def test_every_registered_backend_conforms_and_takes_a_time_limit(tiny, monkeypatch, name):
    monkeypatch.setenv("UUV_OCP_COMPILED", "0")
    backend = new_solver(tiny, name)
    assert isinstance(backend, Backend) and isinstance(backend, TimeLimited)
    assert takes_time_limit(backend)
    check_backend(backend, name)


def test_a_plain_plugin_serves_without_a_deadline_and_is_named_with_one(tiny, registered):
    class Hold:
        name = "hold"

        def __init__(self, problem, options=None):
            self.inner = uo.solvers.IpoptSolver(problem)

        def solve(self, p, warm_start=None, rng=None):
            return self.inner.solve(p, warm_start)

    registered.append("hold")
    uo.register_solver("hold", Hold)
    assert not takes_time_limit(new_solver(tiny, "hold"))
    result = uo.solve(tiny, "multistart-hold", x0=np.zeros(6), options={"starts": 1})
    assert result.solver == "multistart-hold"
    with pytest.raises(ValueError, match=r"deadline.*time_limit.*Hold does not"):
        new_solver(tiny, "multistart-hold", {"deadline": 1.0})
