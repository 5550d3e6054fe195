"""Every bad input gets a clear error naming the argument; nothing crashes or passes silently.

One table of bad inputs over the public entry points (API) and one over the command line.  An
API case must raise ``ValueError`` or ``TypeError`` whose message matches the pattern (it names
the argument, and usually what was expected); no message may show a numpy repr such as
``np.float64(0.0)``.  A CLI case must return exit status 2 with exactly one line on standard
error naming the flag, and nothing may run.  Property tests (hypothesis) check that the
validation of ``Vehicle`` and ``Weights`` accepts every valid input and rejects every invalid
one, and that a reference evaluates to finite states on its window.
"""

from __future__ import annotations

import dataclasses
import math
import re
import warnings
from collections.abc import Callable

import casadi as ca
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import uuv_ocp as uo
from uuv_ocp import cli
from uuv_ocp.tracking import ReferenceSpeedWarning

REFERENCE = uo.Reference.paper("s2")
VEHICLE = uo.Vehicle.rexrov()
PROBLEM = uo.TrackingProblem(VEHICLE, REFERENCE, horizon=5)
X0 = REFERENCE.evaluate([3.0])[0]
NUMPY_REPR = re.compile(r"np\.(float|int)\d*\(|array\(")


def _ocp() -> uo.Ocp:
    ocp = uo.Ocp(horizon=4, dt=0.1, name="bad_inputs")
    x = ocp.state("x")
    u = ocp.control("u", lower=-1.0, upper=1.0)
    a = ocp.parameter("a")
    ocp.set_der(x, a * u)
    ocp.add_stage_cost(x**2 + u**2)
    return ocp


OCP = _ocp()


def _controller(**kw) -> uo.NMPC:
    return uo.NMPC(PROBLEM, "ipopt", **kw)


def _simulate(**kw):
    return uo.simulate(_controller(), X0, kw.pop("duration", 0.3), t0=kw.pop("t0", 3.0), **kw)


def _reference(**kw) -> uo.Reference:
    fields = {"path_x": lambda t: 0.5 * t, "path_y": lambda t: ca.sin(t), **kw}
    return uo.Reference.from_xy(fields.pop("path_x"), fields.pop("path_y"), **fields)


def _problem(**kw) -> uo.TrackingProblem:
    fields = {"vehicle": VEHICLE, "reference": REFERENCE, "horizon": 5, **kw}
    return uo.TrackingProblem(**fields)


def _solve(solver="ipopt", **kw):
    fields = {"x0": X0, "t0": 3.0, **kw}
    return uo.solve(fields.pop("problem", PROBLEM), solver, **fields)


def _vehicle(**kw) -> uo.Vehicle:
    fields = {
        "mass": 1.0,
        "inertia": 1.0,
        "added_mass": (0.0, 0.0, 0.0),
        "linear_damping": (1.0, 1.0, 1.0),
        "quadratic_damping": (0.0, 0.0, 0.0),
        **kw,
    }
    return uo.Vehicle(**fields)


def _minimize(**kw):
    fields = {"fun": lambda X: np.sum(X**2, axis=1), "lower": -np.ones(2), "upper": np.ones(2), **kw}
    return uo.minimize(fields.pop("fun"), fields.pop("lower"), fields.pop("upper"), **fields)


def _generate(**kw):
    fields = {"problem": PROBLEM, "directory": "unused-out", "compile": False, **kw}
    return uo.generate_c(fields.pop("problem"), fields.pop("directory"), **fields)


NAN, INF = math.nan, math.inf


def _declared_ocp(build: Callable[[uo.Ocp, ca.SX, ca.SX], object], horizon: int = 4) -> uo.Ocp:
    """Return a one-state Ocp with ``build(ocp, x, u)`` applied (the call under test)."""
    ocp = uo.Ocp(horizon=horizon, dt=0.1, name="issue31")
    x = ocp.state("x")
    u = ocp.control("u", lower=-1.0, upper=1.0)
    build(ocp, x, u)
    return ocp


def _with_dynamics(ocp: uo.Ocp, x: ca.SX, u: ca.SX) -> None:
    ocp.set_der(x, u)
    ocp.add_stage_cost(x**2 + u**2)


def _plugin(solver: str, plugin_options: dict):
    return uo.get_solver(PROBLEM, solver, {"plugin_options": plugin_options})


def _kink(t):
    return ca.fabs(t - 5.0)


def _step(t):
    return ca.if_else(t > 5.0, 5.0, 0.0)


# issue 31 §7: each crashed (a traceback from CasADi or numpy) or passed silently before
ISSUE31_CASES: list[tuple[str, Callable[[], object], type[Exception], str]] = [
    # -- crashes
    (
        "i31-set_der-undeclared-symbol",
        lambda: _declared_ocp(lambda o, x, u: o.set_der(x, ca.SX.sym("q") * u)),
        ValueError,
        r"derivative of state 'x' depends on undeclared symbol\(s\) \['q'\]",
    ),
    (
        "i31-state-size-huge",
        lambda: uo.Ocp().state("z", 10**12),
        ValueError,
        r"size of state 'z' must be an integer in \[1, 100000\] .*got 1000000000000",
    ),
    (
        "i31-control-size-huge",
        lambda: uo.Ocp().control("w", 10**12),
        ValueError,
        r"size of control 'w' must be an integer in \[1, 100000\]",
    ),
    (
        "i31-parameter-size-huge",
        lambda: uo.Ocp().parameter("p", 10**9),
        ValueError,
        r"size of parameter 'p' must be an integer in \[1, 100000\]",
    ),
    (
        "i31-plugin_options-ipopt-type",
        lambda: _plugin("ipopt", {"ipopt.tol": "abc"}),
        ValueError,
        r"options\['plugin_options'\]\['ipopt.tol'\] = 'abc' is refused by CasADi's 'ipopt' .*wrong type",
    ),
    (
        "i31-plugin_options-ipopt-nested-type",
        lambda: _plugin("ipopt", {"ipopt": {"print_level": 0, "tol": "abc"}}),
        ValueError,
        r"options\['plugin_options'\]\['ipopt'\]\['tol'\] = 'abc' is refused",
    ),
    (
        "i31-plugin_options-ipopt-unknown",
        lambda: _plugin("ipopt", {"bogus": 1}),
        ValueError,
        r"options\['plugin_options'\]\['bogus'\] = 1 is refused by CasADi's 'ipopt' .*Unknown option: bogus",
    ),
    (
        "i31-plugin_options-ipopt-own-unknown",
        lambda: _plugin("ipopt", {"ipopt.no_such_option": 1}),
        ValueError,
        r"\['ipopt.no_such_option'\] = 1 is refused .*No such IPOPT option: no_such_option",
    ),
    (
        "i31-plugin_options-ipopt-range",
        lambda: _plugin("ipopt", {"ipopt.tol": -1.0}),
        ValueError,
        r"\['ipopt.tol'\] = -1.0 is refused .*Invalid options",
    ),
    (
        "i31-plugin_options-sqp-unknown",
        lambda: _plugin("sqp", {"bogus": 1}),
        ValueError,
        r"\['bogus'\] = 1 is refused by CasADi's 'sqpmethod'",
    ),
    (
        "i31-plugin_options-sqp-type",
        lambda: _plugin("sqp", {"tol_du": "abc"}),
        ValueError,
        r"\['tol_du'\] = 'abc' is refused .*Illegal type for tol_du",
    ),
    (
        "i31-plugin_options-fatrop-own-unknown",
        lambda: _plugin("fatrop", {"fatrop.bogus": 1}),
        ValueError,
        r"\['fatrop.bogus'\] = 1 is refused by CasADi's 'fatrop' .*not supported: bogus",
    ),
    (
        "i31-plugin_options-fatrop-other-plugin",
        lambda: _plugin("fatrop", {"ipopt.tol": 1e-8}),
        ValueError,
        r"\['ipopt.tol'\] = 1e-08 is refused by CasADi's 'fatrop' .*Unknown option: ipopt",
    ),
    (
        "i31-compare-seed-negative",
        lambda: uo.compare(PROBLEM, ["ipopt"], x0=X0, t0=3.0, seed=-1),
        ValueError,
        r"^seed must be an integer >= 0, got -1$",
    ),
    # -- silent before
    (
        "i31-reference-kink",
        lambda: _reference(path_x=lambda t: t, path_y=_kink, t_end=10.0),
        ValueError,
        r"must be continuous in position and velocity .*its velocity jumps by [0-9.]+ m/s at t = 5 s",
    ),
    (
        "i31-reference-5m-jump",
        lambda: _reference(path_x=lambda t: t, path_y=_step, t_end=10.0),
        ValueError,
        r"its position jumps by 5 m at t = 5 s",
    ),
    (
        "i31-reference-speed-kink",
        lambda: _reference(path_x=lambda t: ca.if_else(t > 3.0, 2.0 * t - 3.0, t), path_y=lambda t: 0 * t),
        ValueError,
        r"its velocity jumps by 1 m/s at t = 3 s",
    ),
    (
        "i31-reference-heading-jump",
        lambda: _reference(
            path_x=lambda t: 0 * t, path_y=lambda t: 0 * t, heading=lambda t: ca.if_else(t > 5.0, 1.0, 0.0)
        ),
        ValueError,
        r"its heading jumps by 1 rad at t = 5 s",
    ),
    (
        "i31-reference-spatial-jump",
        lambda: uo.Reference.from_xyz(lambda t: t, lambda t: 0 * t, _step, t_end=10.0),
        ValueError,
        r"its position jumps by 5 m at t = 5 s",
    ),
    (
        "i31-waypoints-1e300",
        lambda: uo.Reference.waypoints([[0, 0], [1e300, 0]], 1.0, 1.0),
        ValueError,
        r"points must lie within ±1e\+09 m .*points\[1\] = \(1e\+300, 0.0\)",
    ),
    (
        "i31-from_xy-1e300",
        lambda: _reference(path_x=lambda t: 1e300 + t),
        ValueError,
        r"position \(1e\+300, 0.0\) m at t = 0 s lies beyond ±1e\+09 m",
    ),
    (
        "i31-hold-1e300",
        lambda: uo.Reference.hold((1e300, 0.0, 0.0)),
        ValueError,
        r"position \(1e\+300, 0.0\) m at t = 0 s lies beyond",
    ),
    ("i31-vehicle-mass-1e308", lambda: _vehicle(mass=1e308), ValueError, r"^mass must be at most 1e\+09 kg"),
    (
        "i31-vehicle-mass-1e-300",
        lambda: _vehicle(mass=1e-300),
        ValueError,
        r"^mass must be at least 1e-06 kg",
    ),
    (
        "i31-vehicle-damping-1e12",
        lambda: _vehicle(linear_damping=(1.0, 1e12, 1.0)),
        ValueError,
        r"^linear_damping must be at most 1e\+09 .*got 1e\+12 \(entry 1\)",
    ),
    (
        "i31-vehicle6dof-mass-1e308",
        lambda: dataclasses.replace(uo.Vehicle6DOF.bluerov2_heavy(), mass=1e308),
        ValueError,
        r"^mass must be at most 1e\+09 kg",
    ),
    (
        "i31-weights-all-zero",
        lambda: uo.Weights(pose=(0,) * 3, velocity=(0,) * 3, rate=(0,) * 3, terminal=(0,) * 6),
        ValueError,
        r"weights.pose, weights.velocity and weights.terminal must not all be zero",
    ),
    (
        "i31-weights-no-tracking-cost",
        lambda: _problem(terminal="none", weights=uo.Weights(pose=(0,) * 3, velocity=(0,) * 3)),
        ValueError,
        r"weights.pose and weights.velocity must not all be zero with terminal='none'",
    ),
    (
        "i31-weights-pose-2",
        lambda: uo.Weights(pose=(1.0, 1.0)),
        ValueError,
        r"^weights.pose must have 3 entries or more \(one per pose state: 3-DOF x, y, psi; .*\), got 2",
    ),
    (
        "i31-weights-terminal-3",
        lambda: uo.Weights(terminal=(1.0, 1.0, 1.0)),
        ValueError,
        r"^weights.terminal must have 6 entries .*got 3",
    ),
    (
        "i31-weights-velocity-6",
        lambda: uo.Weights(velocity=(1.0,) * 6),
        ValueError,
        r"^weights.velocity must have 3 entries",
    ),
    (
        "i31-simulate-parameters-tracking",
        lambda: _simulate(parameters={"a": 1.0}),
        ValueError,
        r"parameters is for an Ocp; a TrackingProblem takes its parameters from the reference",
    ),
    (
        "i31-compare-no-solver",
        lambda: uo.compare(PROBLEM, [], x0=X0, t0=3.0),
        ValueError,
        r"solvers must be a non-empty list of solver names, e.g. \['ipopt'\], got \[\]",
    ),
    (
        "i31-compare-solvers-str",
        lambda: uo.compare(PROBLEM, "ipopt", x0=X0, t0=3.0),
        ValueError,
        r"solvers must be a non-empty list of solver names",
    ),
    (
        "i31-subject_to-nan",
        lambda: _declared_ocp(lambda o, x, u: o.subject_to(x <= NAN)),
        ValueError,
        r"constraint .* must hold no NaN, got the constant nan",
    ),
    (
        "i31-bounded-nan-expression",
        lambda: _declared_ocp(lambda o, x, u: o.bounded(-1.0, x * NAN, 1.0)),
        ValueError,
        r"constraint .* must hold no NaN",
    ),
    (
        "i31-stage-cost-nan",
        lambda: _declared_ocp(lambda o, x, u: o.add_stage_cost(NAN * x**2)),
        ValueError,
        r"stage cost must hold finite numbers \(no NaN or inf\), got the constant nan",
    ),
    (
        "i31-terminal-residual-inf",
        lambda: _declared_ocp(lambda o, x, u: o.add_terminal_cost(residual=x - INF)),
        ValueError,
        r"terminal cost residual must hold finite numbers",
    ),
    (
        "i31-set_der-nan",
        lambda: _declared_ocp(lambda o, x, u: o.set_der(x, u + NAN)),
        ValueError,
        r"derivative of state 'x' must hold finite numbers",
    ),
    (
        "i31-from_xy-constant",
        lambda: _reference(path_x=lambda t: 0 * t + 1.0, path_y=lambda t: 0 * t + 2.0, t_end=10.0),
        ValueError,
        r"does not move: its speed is below 1e-06 m/s at every sampled time of \[0, 10\] s",
    ),
    (
        "i31-from_xy-nan",
        lambda: _reference(path_x=lambda t: NAN * t),
        ValueError,
        r"its position is not finite at t = 0.0 s",
    ),
    (
        "i31-from_xy-nan-later",
        lambda: _reference(path_y=lambda t: ca.sqrt(4.0 - t), t_end=10.0),
        ValueError,
        r"its position is not finite at t = 4.0\d* s",
    ),
]

# (id, call, exception type, pattern the message must match)
API_CASES: list[tuple[str, Callable[[], object], type[Exception], str]] = [
    # -- references
    ("paper-list", lambda: uo.Reference.paper(["s1"]), ValueError, r"reference name must be one of"),
    ("paper-none", lambda: uo.Reference.paper(None), ValueError, r"reference name must be one of"),
    ("paper-unknown", lambda: uo.Reference.paper("s42"), ValueError, r"reference name .*'s42'"),
    ("from_xy-path_x-number", lambda: _reference(path_x=3.0), ValueError, r"path_x must be a callable"),
    ("from_xy-name-none", lambda: _reference(name=None), ValueError, r"name must be a string, got None"),
    ("from_xy-t_start-str", lambda: _reference(t_start="a"), ValueError, r"t_start must be a real number"),
    ("from_xy-t_end-before", lambda: _reference(t_end=-1.0), ValueError, r"t_end must be > t_start"),
    ("from_xy-t_end-nan", lambda: _reference(t_end=NAN), ValueError, r"t_end must be > t_start"),
    (
        "from_xy-path_y-vector",
        lambda: _reference(path_y=lambda t: ca.vertcat(t, t)),
        ValueError,
        r"path_y must return a scalar",
    ),
    (
        "from_xy-path_x-fails",
        lambda: _reference(path_x=lambda t: t.no_such_method()),
        ValueError,
        r"path_x must accept a casadi SX symbol",
    ),
    (
        "from_xy-nan-position",
        lambda: _reference(path_x=lambda t: float("nan"), t_end=10.0).evaluate([0.0]),
        ValueError,
        r"position is not finite at t = 0",
    ),
    (
        "from_xy-vanishing-speed",
        lambda: _reference(path_x=lambda t: (t - 1.0) ** 3, path_y=lambda t: 0 * t).evaluate([1.0]),
        ValueError,
        r"vanishing or non-finite speed at t = 1.0 s \(speed 0(\.0)? m/s\)",
    ),
    ("evaluate-str", lambda: REFERENCE.evaluate(["a"]), ValueError, r"times must be real numbers"),
    ("evaluate-nan", lambda: REFERENCE.evaluate([NAN]), ValueError, r"times must be finite, got \[nan\]"),
    ("evaluate-decreasing", lambda: REFERENCE.evaluate([2.0, 1.0]), ValueError, r"times must be non-decr"),
    ("evaluate-outside", lambda: uo.Reference.paper("s3").evaluate([0.0]), ValueError, r"defined on t in"),
    ("initial_state-nan", lambda: REFERENCE.initial_state(NAN), ValueError, r"t0 must be finite"),
    ("hold-pose-str", lambda: uo.Reference.hold("x"), ValueError, r"pose"),
    ("hold-duration-0", lambda: uo.Reference.hold((0, 0, 0), duration=0), ValueError, r"duration"),
    ("waypoints-one", lambda: uo.Reference.waypoints([[0, 0]], 1.0, 1.0), ValueError, r"points"),
    ("waypoints-speed", lambda: uo.Reference.waypoints([[0, 0], [5, 0]], -1.0, 1.0), ValueError, r"speed"),
    (
        "lawnmower-lanes",
        lambda: uo.Reference.lawnmower(width=10, spacing=2, lanes=0, speed=1.0),
        ValueError,
        r"lanes",
    ),
    # -- vehicles and weights
    ("vehicle-mass-negative", lambda: _vehicle(mass=-1.0), ValueError, r"mass must be a finite number > 0"),
    ("vehicle-mass-str", lambda: _vehicle(mass="heavy"), ValueError, r"mass must be a real number"),
    ("vehicle-inertia-nan", lambda: _vehicle(inertia=NAN), ValueError, r"inertia must be finite"),
    ("vehicle-added-short", lambda: _vehicle(added_mass=(1, 2)), ValueError, r"added_mass must have shape"),
    (
        "vehicle-damping-neg",
        lambda: _vehicle(linear_damping=(1, -1, 1)),
        ValueError,
        r"linear_damping .*>= 0",
    ),
    ("vehicle-thrust-zero", lambda: _vehicle(max_thrust=(1, 0, 1)), ValueError, r"max_thrust must be > 0"),
    ("vehicle-name", lambda: _vehicle(name=3), ValueError, r"name must be a string"),
    ("weights-pose-neg", lambda: uo.Weights(pose=(-1, 1, 1)), ValueError, r"weights.pose must be >= 0"),
    ("weights-pose-empty", lambda: uo.Weights(pose=()), ValueError, r"weights.pose must be a non-empty"),
    ("weights-rate-str", lambda: uo.Weights(rate="abc"), ValueError, r"weights.rate"),
    ("weights-penalty-0", lambda: uo.Weights(terminal_penalty=0), ValueError, r"weights.terminal_penalty"),
    ("weights-pose-length", lambda: _problem(weights=uo.Weights(pose=(1, 1))), ValueError, r"weights.pose"),
    # -- problems
    ("horizon-huge", lambda: _problem(horizon=10**9), ValueError, r"horizon must be an integer <= 10000"),
    ("horizon-0", lambda: _problem(horizon=0), ValueError, r"horizon must be an integer >= 1"),
    ("horizon-float", lambda: _problem(horizon=2.5), ValueError, r"horizon must be an integer"),
    ("horizon-bool", lambda: _problem(horizon=True), ValueError, r"horizon must be an integer"),
    ("dt-0", lambda: _problem(dt=0), ValueError, r"dt must be a finite number > 0"),
    ("dt-nan", lambda: _problem(dt=NAN), ValueError, r"dt must be finite"),
    ("terminal-unknown", lambda: _problem(terminal="hard"), ValueError, r"terminal must be one of"),
    ("terminal-list", lambda: _problem(terminal=["equality"]), ValueError, r"terminal must be one of"),
    (
        "vehicle-none",
        lambda: _problem(vehicle=None),
        ValueError,
        r"vehicle must implement uuv_ocp.VehicleModel",
    ),
    ("reference-str", lambda: _problem(reference="s2"), ValueError, r"reference must be a uuv_ocp.Reference"),
    ("substeps-0", lambda: _problem(substeps=0), ValueError, r"substeps must be an integer >= 1"),
    ("rate_limits-str", lambda: _problem(rate_limits="no"), ValueError, r"rate_limits must be True or False"),
    ("tube-negative", lambda: _problem(position_tube=-1.0), ValueError, r"position_tube must be"),
    ("weights-dict", lambda: _problem(weights={}), ValueError, r"weights must be a uuv_ocp.Weights"),
    (
        "window-too-short",
        lambda: _problem(reference=uo.Reference.paper("s3"), horizon=400),
        ValueError,
        r"horizon \* dt = 40.0 s exceeds the reference window",
    ),
    ("ocp-horizon-huge", lambda: uo.Ocp(horizon=10**9), ValueError, r"horizon must be an integer <= 10000"),
    ("ocp-dt-negative", lambda: uo.Ocp(dt=-1.0), ValueError, r"dt must be a finite number > 0"),
    ("ocp-integrator", lambda: uo.Ocp(integrator="euler2"), ValueError, r"integrator must be one of"),
    ("ocp-state-name", lambda: uo.Ocp().state("x y"), ValueError, r"state name must be a Python identifier"),
    (
        "ocp-control-bounds",
        lambda: uo.Ocp().control("u", lower=1.0, upper=-1.0),
        ValueError,
        r"lower of control 'u' must be <= upper",
    ),
    (
        "ocp-parameters-str",
        lambda: OCP.parameters([0.0], "abc"),
        ValueError,
        r"parameters must be a dict of name -> value, got 'abc'",
    ),
    (
        "ocp-parameter-str",
        lambda: OCP.parameters([0.0], {"a": "x"}),
        ValueError,
        r"parameter 'a' must be numbers",
    ),
    (
        "ocp-parameter-object",
        lambda: OCP.parameters([0.0], {"a": object()}),
        ValueError,
        r"parameter 'a' must be numbers",
    ),
    ("ocp-parameter-missing", lambda: OCP.parameters([0.0], {}), ValueError, r"parameter 'a' is missing"),
    ("ocp-x0-huge", lambda: OCP.parameters([1e300], {"a": 1.0}), ValueError, r"x0 must have every entry"),
    ("ocp-t0", lambda: uo.solve(OCP, "ipopt", x0=[0.0], t0=1.0), ValueError, r"t0 is a TrackingProblem"),
    # -- solve and its instance
    ("solver-list", lambda: _solve(["ipopt"]), ValueError, r"solver must be a string"),
    ("solver-unknown", lambda: _solve("newton"), ValueError, r"solver must be one of .*'newton'"),
    ("solver-hybrid-unknown", lambda: _solve("igwo+foo"), ValueError, r"solver must be one of .*'igwo\+foo'"),
    ("problem-none", lambda: _solve(problem=None), ValueError, r"problem must be a uuv_ocp.Ocp"),
    ("x0-shape", lambda: _solve(x0=[0.0, 0.0]), ValueError, r"x0 must have shape \(6,\)"),
    ("x0-nan", lambda: _solve(x0=[NAN] * 6), ValueError, r"x0 must be finite"),
    ("x0-str", lambda: _solve(x0="abc"), ValueError, r"x0 must be a real array"),
    (
        "x0-implausible",
        lambda: _solve(x0=[1e300, 0, 0, 0, 0, 0]),
        ValueError,
        r"x0 must have every entry within ±1e\+09 .*got 1e\+300 at index 0",
    ),
    ("t0-nan", lambda: _solve(t0=NAN), ValueError, r"t0 must be finite"),
    (
        "t0-outside",
        lambda: _solve(problem=_problem(reference=uo.Reference.paper("s3")), t0=0.0),
        ValueError,
        r"t0 must lie in",
    ),
    (
        "u_prev-above-box",
        lambda: _solve(u_prev=[1e9, 0, 0]),
        ValueError,
        r"u_prev must lie inside the control",
    ),
    ("u_prev-shape", lambda: _solve(u_prev=[0.0]), ValueError, r"u_prev must have shape \(3,\)"),
    ("current-shape", lambda: _solve(current=[0.1, 0.2, 0.3]), ValueError, r"current must"),
    ("current-str", lambda: _solve(current="strong"), ValueError, r"current must be numbers"),
    (
        "current-implausible",
        lambda: _solve(current=[1e300, 0.0]),
        ValueError,
        r"current must have every entry",
    ),
    ("options-str", lambda: _solve(options="fast"), ValueError, r"options must be a dict"),
    ("options-unknown", lambda: _solve(options={"tol": 1}), ValueError, r"unknown options .*'tol'"),
    ("warm_start-str", lambda: _solve(warm_start="yes"), ValueError, r"warm_start must be a uuv_ocp Iterate"),
    ("parameters-tracking", lambda: _solve(parameters={"a": 1}), ValueError, r"parameters= is for an Ocp"),
    (
        "score-controls-shape",
        lambda: uo.score(PROBLEM, np.zeros((2, 3)), X0, 3.0),
        ValueError,
        r"controls must have shape \(5, 3\)",
    ),
    # -- solver options
    (
        "penalty_escalation-int",
        lambda: uo.get_solver(PROBLEM, "ipopt", {"penalty_escalation": 5}),
        ValueError,
        r"options\['penalty_escalation'\] of 'ipopt' must be a tuple of factors > 0, e.g. .*got 5$",
    ),
    (
        "penalty_escalation-str",
        lambda: uo.get_solver(PROBLEM, "ipopt", {"penalty_escalation": "ab"}),
        ValueError,
        r"options\['penalty_escalation'\]",
    ),
    (
        "penalty_escalation-negative",
        lambda: uo.get_solver(PROBLEM, "ipopt", {"penalty_escalation": (10.0, -1.0)}),
        ValueError,
        r"options\['penalty_escalation'\] of 'ipopt' entries must be a finite number > 0",
    ),
    (
        "slack_tolerance-negative",
        lambda: uo.get_solver(PROBLEM, "ipopt", {"slack_tolerance": -1}),
        ValueError,
        r"options\['slack_tolerance'\]",
    ),
    ("compiled-str", lambda: uo.get_solver(PROBLEM, "ipopt", {"compiled": "yes"}), ValueError, r"compiled"),
    ("max_iter-0", lambda: uo.get_solver(PROBLEM, "ipopt", {"max_iter": 0}), ValueError, r"max_iter"),
    (
        "terminal_strategy",
        lambda: uo.get_solver(PROBLEM, "ipopt", {"terminal_strategy": "x"}),
        ValueError,
        r"terminal_strategy",
    ),
    (
        "plugin_options-int",
        lambda: uo.get_solver(PROBLEM, "ipopt", {"plugin_options": 3}),
        ValueError,
        r"plugin_options",
    ),
    (
        "swarm-population-2",
        lambda: uo.get_solver(PROBLEM, "igwo", {"population": 2}),
        ValueError,
        r"population",
    ),
    (
        "swarm-iterations-0",
        lambda: uo.get_solver(PROBLEM, "igwo", {"iterations": 0}),
        ValueError,
        r"iterations",
    ),
    ("swarm-seed-str", lambda: uo.get_solver(PROBLEM, "igwo", {"seed": "abc"}), ValueError, r"seed"),
    (
        "swarm-rng_thread-str",
        lambda: uo.get_solver(PROBLEM, "igwo", {"rng_thread": "yes"}),
        ValueError,
        r"options\['rng_thread'\] of 'igwo' must be True or False",
    ),
    (
        "get_solver-problem",
        lambda: uo.get_solver(None, "ipopt"),
        ValueError,
        r"problem must be a uuv_ocp.Ocp",
    ),
    ("register-plus", lambda: uo.register_solver("a+b", lambda p, o: None), ValueError, r"solver name"),
    ("register-factory", lambda: uo.register_solver("mine", 3), ValueError, r"factory must be callable"),
    # -- NMPC and simulate
    ("nmpc-warm_start-str", lambda: _controller(warm_start="no"), ValueError, r"warm_start must be True or"),
    ("nmpc-seed-bool", lambda: _controller(seed=True), ValueError, r"seed must be an integer >= 0, got True"),
    ("nmpc-seed-negative", lambda: _controller(seed=-1), ValueError, r"seed must be an integer >= 0"),
    ("nmpc-solver-list", lambda: uo.NMPC(PROBLEM, ["ipopt"]), ValueError, r"solver must be a string"),
    (
        "simulate-current-str",
        lambda: _simulate(current="strong"),
        ValueError,
        r"current must be a uuv_ocp.Current or None, got 'strong'",
    ),
    (
        "simulate-current-tuple",
        lambda: _simulate(current=(0.3, 0.5)),
        ValueError,
        r"current must be a uuv_ocp",
    ),
    (
        "simulate-noise-float",
        lambda: _simulate(noise=0.1),
        ValueError,
        r"noise must be a uuv_ocp.Measurement",
    ),
    (
        "simulate-seed-str",
        lambda: _simulate(seed="abc"),
        ValueError,
        r"seed must be an integer >= 0, got 'abc'",
    ),
    (
        "simulate-seed-bool",
        lambda: _simulate(seed=True),
        ValueError,
        r"seed must be an integer >= 0, got True",
    ),
    (
        "simulate-current_known",
        lambda: _simulate(current_known="no"),
        ValueError,
        r"current_known must be True",
    ),
    ("simulate-progress", lambda: _simulate(progress="x"), ValueError, r"progress must be True or False"),
    (
        "simulate-duration-neg",
        lambda: _simulate(duration=-1.0),
        ValueError,
        r"duration must be a finite number",
    ),
    ("simulate-duration-nan", lambda: _simulate(duration=NAN), ValueError, r"duration must be finite"),
    (
        "simulate-substeps",
        lambda: _simulate(plant_substeps=0),
        ValueError,
        r"plant_substeps must be an integer",
    ),
    ("simulate-t0-nan", lambda: _simulate(t0=NAN), ValueError, r"t0 must be finite"),
    (
        "simulate-plant-str",
        lambda: _simulate(plant="rexrov"),
        ValueError,
        r"plant must implement uuv_ocp.VehicleModel",
    ),
    (
        "simulate-controller",
        lambda: uo.simulate("ipopt", X0, 1.0),
        ValueError,
        r"controller must be a uuv_ocp",
    ),
    ("current-speed-neg", lambda: uo.Current(speed=-1.0), ValueError, r"speed must be a finite number >= 0"),
    (
        "current-over-max",
        lambda: uo.Current(speed=3.0, max_speed=2.0),
        ValueError,
        r"speed must be <= max_spe",
    ),
    ("noise-std-neg", lambda: uo.MeasurementNoise((-1.0,) * 6), ValueError, r"std must be >= 0"),
    # -- minimize
    ("minimize-fun", lambda: _minimize(fun=3), ValueError, r"fun must be callable"),
    ("minimize-method", lambda: _minimize(method="newton"), ValueError, r"method must be one of"),
    ("minimize-population", lambda: _minimize(population=2), ValueError, r"population"),
    ("minimize-box", lambda: _minimize(lower=np.ones(2), upper=-np.ones(2)), ValueError, r"lower"),
    ("minimize-seed-bool", lambda: _minimize(seed=True), ValueError, r"seed must be an int"),
    ("minimize-iterations", lambda: _minimize(iterations=-1), ValueError, r"iterations"),
    # -- code generation
    (
        "generate_c-problem-none",
        lambda: _generate(problem=None),
        TypeError,
        r"problem must be an Ocp or a Tr",
    ),
    ("generate_c-directory-none", lambda: _generate(directory=None), TypeError, r"directory must be a path"),
    ("generate_c-tolerance-neg", lambda: _generate(tolerance=-1), ValueError, r"tolerance must be a finite"),
    ("generate_c-tolerance-nan", lambda: _generate(tolerance=NAN), ValueError, r"tolerance must be finite"),
    (
        "generate_c-population-2",
        lambda: _generate(population=2),
        ValueError,
        r"population must be an integer >= 4",
    ),
    (
        "generate_c-functions",
        lambda: _generate(functions=("foo",)),
        ValueError,
        r"functions must be a non-empty",
    ),
    ("generate_c-functions-str", lambda: _generate(functions="cost"), ValueError, r"functions must be a"),
    ("generate_c-seed-bool", lambda: _generate(seed=True), ValueError, r"seed must be an integer >= 0"),
    ("generate_c-compile-str", lambda: _generate(compile="no"), ValueError, r"compile must be True or False"),
    ("generate_c-flags-str", lambda: _generate(flags="-O2"), ValueError, r"flags must be a tuple of strings"),
    # -- comparison
    (
        "compare-solver",
        lambda: uo.compare(PROBLEM, ["newton"], x0=X0, t0=3.0),
        ValueError,
        r"solver must be one",
    ),
    (
        "api-compare-t0-nan",
        lambda: uo.compare(PROBLEM, ["ipopt"], x0=X0, t0=NAN),
        ValueError,
        r"t0 must be fin",
    ),
    *ISSUE31_CASES,
]


@pytest.mark.parametrize(
    ("call", "error", "pattern"), [c[1:] for c in API_CASES], ids=[c[0] for c in API_CASES]
)
def test_bad_input_is_named(call, error, pattern):
    with pytest.raises(error, match=pattern) as info:
        call()
    message = str(info.value)
    assert not NUMPY_REPR.search(message), f"numpy repr in the message: {message}"
    assert "\n" not in message.strip(), f"multi-line message: {message}"


def test_case_ids_are_unique():
    ids = [c[0] for c in API_CASES] + [c[0] for c in CLI_CASES]
    assert len(ids) == len(set(ids))


# -- silent before: now a warning or a result that says what happened -----------------------------


def test_reference_faster_than_the_vehicle_warns_with_the_time():
    fast = uo.Reference.from_xy(lambda t: 0.5 * t + 0.05 * t**2, lambda t: 0 * t, "accelerating", t_end=60.0)
    problem = uo.TrackingProblem(VEHICLE, fast, horizon=5, terminal="none")
    top, _ = VEHICLE.max_horizontal_speed()
    crossing = (top - 0.5) / 0.1  # d/dt (0.5 t + 0.05 t^2) = 0.5 + 0.1 t
    with pytest.warns(ReferenceSpeedWarning, match=r"'accelerating' is faster than the vehicle") as record:
        # the controller sees [15.5, 15.5 + (2 steps + N = 5) 0.1 s]: the crossing at ~16.05 s
        uo.simulate(uo.NMPC(problem, "ipopt"), fast.evaluate([15.5])[0], 0.2, t0=15.5)
    message = str(record[0].message)
    when = float(re.search(r"from t = ([0-9.]+) s", message).group(1))
    assert abs(when - math.ceil(crossing * 10) / 10) <= 0.1 + 1e-9
    assert issubclass(ReferenceSpeedWarning, RuntimeWarning)


def test_reference_within_the_top_speed_does_not_warn():
    with warnings.catch_warnings():
        warnings.simplefilter("error", ReferenceSpeedWarning)
        uo.simulate(_controller(), X0, 0.2, t0=3.0)


@pytest.mark.parametrize("method", ["igwo", "gwo", "ssa", "pso"])
def test_minimize_with_an_always_nan_objective_says_so(method):
    result = _minimize(fun=lambda X: np.full(len(X), np.nan), iterations=3, seed=0, method=method)
    assert result is not None and not result.success and result.fun == math.inf
    assert "no finite value" in result.message


# -- issue 31 §7, cases that are not one call raising ------------------------------------------


def test_cost_ratio_of_a_zero_best_cost():
    """A held pose costs exactly 0: the ratio was 0 / 0 (ZeroDivisionError in the CLI)."""
    from uuv_ocp.studies.compare import cost_ratio

    assert cost_ratio(0.0, 0.0) == 1.0
    assert cost_ratio(2.5, 0.0) == math.inf
    assert cost_ratio(3.0, 1.5) == 2.0
    assert math.isnan(cost_ratio(math.nan, 0.0))


def test_cli_compare_on_a_held_pose_from_rest(capsys, tmp_path, monkeypatch):
    """`compare -r hold 0,0,0 --t0 0`: every cost is 0 (the vehicle rests on the pose)."""
    monkeypatch.chdir(tmp_path)
    assert cli.main(["compare", "-r", "hold", "0,0,0", "--solvers", "ipopt", "--t0", "0"]) == 0
    captured = capsys.readouterr()
    row = next(line for line in captured.out.splitlines() if "ipopt" in line)
    cost, ratio = row.split()[2:4]
    assert float(cost) == 0.0 and float(ratio) == 1.0, row


def test_cli_waypoints_beyond_the_plausibility_bound(capsys, tmp_path, monkeypatch):
    """Waypoints at 1e300 ran and printed nan in the table, exit status 0."""
    monkeypatch.chdir(tmp_path)
    (tmp_path / "far.csv").write_text("0,0\n1e300,0\n")
    assert cli.main(["track", "-r", "waypoints", "far.csv", "--duration", "1"]) == 2
    captured = capsys.readouterr()
    lines = captured.err.strip().splitlines()
    assert len(lines) == 1 and captured.out == "", captured
    assert re.search(r"^error: --reference: .*points must lie within ±1e\+09 m", lines[0]), lines[0]


def test_horizon_one_solves():
    """N = 1 is in the documented range [1, 10000]; it failed with "start must be < horizon = 1".

    With N = 1 the cost is the rate term of u_0 and the terminal term of x_1: two backends
    (interior point and SQP) must agree on that one-interval problem.
    """
    problem = _problem(horizon=1, terminal="none")
    ipopt, sqp = (_solve(solver, problem=problem) for solver in ("ipopt", "sqp"))
    assert ipopt.success and sqp.success and ipopt.controls.shape == (1, 3)
    np.testing.assert_allclose(ipopt.controls, sqp.controls, atol=1e-4 * float(np.max(VEHICLE.max_thrust)))
    assert ipopt.cost == pytest.approx(sqp.cost, rel=1e-6)
    # the paper's terminal equality cannot hold after one step: the soft fallback solves it
    held = _solve(problem=_problem(horizon=1))
    assert held.controls.shape == (1, 3) and np.isfinite(held.cost)


def test_plugin_options_that_casadi_accepts_still_pass():
    """The plugin_options check must not refuse valid settings (those tests and benchmarks use)."""
    for solver, options in [
        ("ipopt", {"ipopt.tol": 1e-12, "ipopt.bound_relax_factor": 0.0}),
        ("ipopt", {"ipopt": {"tol": 1e-10}, "oracle_options": {"ad_weight": 1.0}}),
        ("fatrop", {"fatrop.mu_init": 1e-4}),
        ("sqp", {"tol_du": 1e-12, "tol_pr": 1e-12}),
    ]:
        assert _plugin(solver, options).plugin_options == options


@pytest.mark.parametrize(
    "make",
    [
        lambda: uo.Reference.paper("s8"),
        lambda: uo.Reference.waypoints([(0, 0), (20, 0), (20, 5), (0, 5)], speed=0.5, turn_radius=2.0),
        lambda: uo.Reference.lawnmower(width=30, spacing=6, lanes=4, speed=1.0, depth=3.0),
        lambda: uo.Reference.hold((1.0, 2.0, 0.5)),
        lambda: uo.Reference.from_xy(lambda t: 5e6 + 0.5 * t, lambda t: 4e6 + 2 * ca.sin(0.5 * t)),
    ],
    ids=["s8", "square", "lawnmower-3d", "hold", "utm-coordinates"],
)
def test_smooth_references_pass_the_window_check(make):
    """C¹ paths, curvature jumps of waypoint joints included, are not mistaken for kinks."""
    make().check_window()


# -- command line ------------------------------------------------------------------------------

CLI_CASES: list[tuple[str, list[str], str]] = [
    (
        "track-duration-negative",
        ["track", "--duration", "-5"],
        r"--duration must be a finite number > 0, got -5",
    ),
    (
        "track-duration-nan",
        ["track", "--duration", "nan"],
        r"--duration must be a finite number > 0, got nan",
    ),
    (
        "track-duration-inf",
        ["track", "--duration", "inf"],
        r"--duration must be a finite number > 0, got inf",
    ),
    ("track-duration-short", ["track", "--duration", "0.05"], r"--duration must be at least one sampling"),
    ("track-duration-str", ["track", "--duration", "long"], r"argument --duration: invalid float value"),
    ("track-horizon-0", ["track", "--horizon", "0"], r"--horizon must be an integer in \[1, 10000\], got 0$"),
    ("track-horizon-negative", ["track", "--horizon", "-5"], r"--horizon must be an integer in .*got -5$"),
    ("track-horizon-huge", ["track", "--horizon", "1000000000"], r"--horizon must be an integer in"),
    ("track-horizon-str", ["track", "--horizon", "abc"], r"argument --horizon: invalid int value: 'abc'"),
    ("track-dt-0", ["track", "--dt", "0"], r"--dt must be a finite number > 0, got 0$"),
    ("track-dt-nan", ["track", "--dt", "nan"], r"--dt must be a finite number > 0, got nan$"),
    ("track-s3-horizon-400", ["track", "-r", "s3", "--horizon", "400"], r"--horizon 400 x --dt 0.1 s = 40 s"),
    ("track-solver-hybrid", ["track", "-s", "igwo+foo"], r"--solver must be one of .*'igwo\+foo'"),
    ("track-solver-unknown", ["track", "-s", "newton"], r"--solver must be one of .*'newton'"),
    ("track-reference", ["track", "-r", "s42"], r"--reference must be one of .*s42"),
    ("track-out-proc", ["track", "--out", "/proc/x"], r"--out /proc/x: cannot create the folder"),
    ("track-unknown-flag", ["track", "--bogus"], r"unrecognized arguments: --bogus"),
    ("demo-out-proc", ["demo", "--out", "/proc/x"], r"--out /proc/x: cannot create the folder"),
    ("unknown-command", ["frobnicate"], r"argument command: invalid choice: 'frobnicate'"),
    ("compare-t0-nan", ["compare", "--t0", "nan"], r"--t0 must be a finite number, got nan"),
    ("compare-t0-inf", ["compare", "--t0", "inf"], r"--t0 must be a finite number, got inf"),
    ("compare-t0-outside", ["compare", "-r", "s3", "--t0", "0"], r"t0 must lie in \[1.5, 26.5\] s"),
    ("compare-solvers", ["compare", "--solvers", "ipopt", "newton"], r"--solvers must be one of .*'newton'"),
    ("compare-seed", ["compare", "--seed", "-1"], r"--seed must be an integer >= 0, got -1"),
    ("compare-reference", ["compare", "-r", "s42"], r"--reference must be one of .*'s42'"),
    ("campaign-out", ["campaign", "--trials", "1", "--out", "/proc/x"], r"--out /proc/x: cannot create"),
    ("campaign-trials", ["campaign", "--trials", "0"], r"trials must be an integer >= 1"),
    ("campaign-duration", ["campaign", "--duration", "-1"], r"duration must be a finite number > 0"),
    ("campaign-current", ["campaign", "--max-current", "nan"], r"max_current must be finite"),
    ("campaign-workers", ["campaign", "--workers", "0"], r"--workers must be an integer >= 1, got 0"),
    ("campaign-solver", ["campaign", "-s", "newton"], r"--solver must be one of .*'newton'"),
    ("campaign-executor", ["campaign", "--executor", "cloud"], r"argument --executor: invalid choice"),
    ("codegen-out-proc", ["codegen", "--out", "/proc/x"], r"--out: cannot create the build folder /proc/x"),
    ("codegen-population-2", ["codegen", "--population", "2"], r"--population must be an integer >= 4"),
    ("codegen-horizon-0", ["codegen", "--horizon", "0"], r"--horizon must be an integer in"),
    ("codegen-reference", ["codegen", "-r", "s42"], r"--reference must be one of"),
    ("solver-did-you-mean", ["track", "-s", "ipop"], r"got 'ipop'; did you mean 'ipopt'"),
    ("vehicle-unknown", ["track", "--vehicle", "bluerov"], r"--vehicle must be one of .*'bluerov'"),
    ("vehicle-file", ["compare", "--vehicle", "no.toml"], r"--vehicle must be one of .*existing \.toml"),
    ("waypoints-missing", ["track", "-r", "waypoints"], r"--reference must be one of .*'waypoints'"),
    ("waypoints-no-file", ["track", "-r", "waypoints", "x.csv"], r"--reference: x.csv: cannot read"),
    ("compare-two-references", ["compare", "-r", "s1", "s2"], r"--reference takes one reference here"),
]


@pytest.mark.parametrize(("argv", "pattern"), [c[1:] for c in CLI_CASES], ids=[c[0] for c in CLI_CASES])
def test_bad_flag_is_one_line_and_exit_status_2(argv, pattern, capsys, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)  # default output folders land here, never in the repository
    assert cli.main(argv) == 2
    captured = capsys.readouterr()
    lines = captured.err.strip().splitlines()
    assert len(lines) == 1, captured.err
    assert lines[0].startswith("error: ") and re.search(pattern, lines[0]), lines[0]
    assert captured.out == ""
    assert not (tmp_path / "out" / "runs").exists() or not list((tmp_path / "out" / "runs").iterdir())


def test_no_subcommand_prints_help_and_the_demo_command(capsys):
    assert cli.main([]) == 2
    err = capsys.readouterr().err
    assert "usage: uuv-ocp" in err and "uuv-ocp demo" in err


# -- property tests --------------------------------------------------------------------------------

valid_positive = st.floats(min_value=1e-6, max_value=1e9, allow_nan=False)
valid_nonnegative = st.floats(min_value=0.0, max_value=1e9, allow_nan=False)
invalid_positive = st.one_of(
    st.floats(max_value=0.0), st.just(math.nan), st.just(math.inf), st.just(-math.inf), st.text(max_size=3)
)
invalid_nonnegative = st.one_of(
    st.floats(max_value=-1e-300, allow_infinity=False), st.just(math.nan), st.just(math.inf), st.none()
)
FIELDS = {
    "mass": ("positive", None),
    "inertia": ("positive", None),
    "added_mass": ("nonnegative", 3),
    "linear_damping": ("nonnegative", 3),
    "quadratic_damping": ("nonnegative", 3),
    "max_thrust": ("positive", 3),
    "max_thrust_rate": ("positive", 3),
}


@st.composite
def vehicle_fields(draw, broken: str | None = None):
    """Draw valid ``Vehicle`` keyword arguments, with one field ``broken`` (invalid) if asked."""
    fields = {}
    for name, (kind, length) in FIELDS.items():
        good = valid_positive if kind == "positive" else valid_nonnegative
        bad = invalid_positive if kind == "positive" else invalid_nonnegative
        if length is None:
            fields[name] = draw(bad if name == broken else good)
        else:
            values = draw(st.lists(good, min_size=length, max_size=length))
            if name == broken:
                values[draw(st.integers(0, length - 1))] = draw(bad)
            fields[name] = tuple(values)
    return fields


@settings(max_examples=60, deadline=None)
@given(vehicle_fields())
def test_vehicle_accepts_every_valid_parameter_set(fields):
    vehicle = uo.Vehicle(**fields)
    assert vehicle.mass == pytest.approx(fields["mass"])
    assert np.all(vehicle.max_speed() > 0)


@settings(max_examples=80, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.sampled_from(sorted(FIELDS)).flatmap(lambda name: st.tuples(st.just(name), vehicle_fields(name))))
def test_vehicle_rejects_every_invalid_field_and_names_it(case):
    name, fields = case
    with pytest.raises(ValueError, match=rf"^{name} must"):
        uo.Vehicle(**fields)


@pytest.mark.parametrize("text", ["1", b"1", "2.5"])
def test_a_vector_field_with_text_in_it_is_rejected(text):
    """Numpy reads the text "1" as 1.0; a vehicle field must not (found by the property above)."""
    vehicle = uo.Vehicle.rexrov()
    with pytest.raises(ValueError, match=r"^max_thrust_rate must be 3 real numbers"):
        dataclasses.replace(vehicle, max_thrust_rate=(text, 1.0, 1.0))
    with pytest.raises(ValueError, match=r"^added_mass must be 3 real numbers"):
        dataclasses.replace(vehicle, added_mass=text)


weight_vectors = st.lists(valid_nonnegative, min_size=1, max_size=12).map(tuple)


def _weight_vectors(dof: int, nu: int) -> st.SearchStrategy:
    """pose, velocity, rate, terminal of consistent lengths (dof 3 or 6, nu controls), not all zero."""

    def vector(n: int) -> st.SearchStrategy:
        return st.lists(valid_nonnegative, min_size=n, max_size=n).map(tuple)

    return st.tuples(vector(dof), vector(dof), vector(nu), vector(2 * dof)).filter(
        lambda w: any(w[0] + w[1] + w[3])
    )


@settings(max_examples=60, deadline=None)
@given(
    st.sampled_from([3, 6]).flatmap(
        lambda dof: st.integers(1, 12).flatmap(lambda nu: _weight_vectors(dof, nu))
    ),
    valid_positive,
    valid_positive,
)
def test_weights_accept_every_nonnegative_vector_and_positive_penalty(vectors, rho, tube):
    pose, velocity, rate, terminal = vectors
    weights = uo.Weights(pose, velocity, rate, terminal, terminal_penalty=rho, tube_penalty=tube)
    assert weights.pose == tuple(float(v) for v in pose) and weights.terminal_penalty == rho


@settings(max_examples=80, deadline=None)
@given(
    st.sampled_from(
        ["pose", "velocity", "rate", "terminal", "terminal_penalty", "rate_penalty", "tube_penalty"]
    ),
    st.data(),
)
def test_weights_reject_every_invalid_entry_and_name_it(name, data):
    if name.endswith("penalty"):
        value = data.draw(invalid_positive)
    else:
        value = list(data.draw(weight_vectors))
        value[data.draw(st.integers(0, len(value) - 1))] = data.draw(invalid_nonnegative)
        value = data.draw(st.sampled_from([tuple(value), []]))
    with pytest.raises(ValueError, match=rf"^weights\.{name} must"):
        uo.Weights(**{name: value})


@settings(max_examples=40, deadline=None)
@given(
    amplitude=st.floats(-5.0, 5.0),
    frequency=st.floats(0.0, 2.0),
    phase=st.floats(-math.pi, math.pi),
    speed=st.floats(0.1, 2.0),
    start=st.floats(-10.0, 10.0),
    length=st.floats(0.5, 30.0),
    fractions=st.lists(st.floats(0.0, 1.0), min_size=1, max_size=20),
)
def test_reference_is_finite_everywhere_on_its_window(
    amplitude, frequency, phase, speed, start, length, fractions
):
    """A path with a nonvanishing speed (x moves forward) evaluates finitely on its whole window."""
    reference = uo.Reference.from_xy(
        lambda t: speed * t,
        lambda t: amplitude * ca.sin(frequency * t + phase),
        t_start=start,
        t_end=start + length,
    )
    times = np.sort(start + length * np.asarray(fractions))
    states = reference.evaluate(times)
    assert states.shape == (times.size, 6) and np.all(np.isfinite(states))
    assert np.all(states[:, 3] >= speed * (1 - 1e-12))
    assert abs(states[0, 2]) <= math.pi + 1e-12
