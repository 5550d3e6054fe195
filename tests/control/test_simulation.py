"""Closed loop: tracking accuracy, fallback on failure, disturbances, interruption, saving."""

import casadi as ca
import numpy as np
import pytest

import uuv_ocp as uo
from uuv_ocp.solvers import REGISTRY
from uuv_ocp.solvers.ipopt import IpoptSolver


@pytest.fixture(scope="module")
def s2_run(s2_problem):
    reference = s2_problem.reference
    return uo.simulate(uo.NMPC(s2_problem, "ipopt"), reference.initial_state(0.0), 15.0)


def test_nominal_tracking_converges_after_the_start_transient(s2_run):
    metrics = s2_run.metrics(settle_time=5.0)
    assert metrics["failures"] == 0
    assert metrics["max_abs_ex_settled"] <= 1e-3
    assert metrics["max_abs_ey_settled"] <= 1e-3
    # the start from rest saturates thrust: a real transient, reported as relaxed steps
    assert metrics["relaxed_steps"] > 0
    assert metrics["max_abs_ey"] > 0.1


def test_applied_controls_respect_thrust_and_rate_bounds(s2_run, s2_problem):
    bounds = s2_problem.max_thrust * (1 + 1e-6)
    assert np.all(np.abs(s2_run.controls) <= bounds)
    steps = np.diff(np.vstack([np.zeros(3), s2_run.controls]), axis=0)
    assert np.all(np.abs(steps) <= np.asarray(uo.Vehicle.rexrov().max_thrust_rate) * 0.1 * (1 + 1e-6))


def test_plant_trajectory_is_reproduced_by_an_independent_integrator(s2_run, s2_problem):
    """Replaying the applied controls through scipy's DOP853 gives the same states."""
    from scipy.integrate import solve_ivp

    f = s2_problem.vehicle.dynamics_function()
    state = s2_run.states[0]
    for k in range(20):
        solution = solve_ivp(
            lambda _t, x, u=s2_run.controls[k]: np.array(f(x, u, [0, 0])).ravel(),
            (0, 0.1),
            state,
            method="DOP853",
            rtol=1e-11,
            atol=1e-11,
        )
        state = solution.y[:, -1]
    np.testing.assert_allclose(state, s2_run.states[20], atol=1e-7)


def test_recorded_plant_substeps_match_an_independent_integrator(s2_problem, tmp_path):
    """Every plant sub-step of a run against scipy's DOP853 from the node before it."""
    from scipy.integrate import solve_ivp

    reference = s2_problem.reference
    run = uo.simulate(
        uo.NMPC(s2_problem, "ipopt"),
        reference.initial_state(0.0),
        1.0,
        plant_substeps=5,
        record_substeps=True,
        current=uo.Current(speed=0.3, direction=0.5),
    )
    assert run.substep_states.shape == (5 * run.controls.shape[0] + 1, 6)
    np.testing.assert_array_equal(run.substep_states[::5], run.states)
    np.testing.assert_allclose(
        run.substep_t, np.linspace(run.t[0], run.t[-1], run.substep_t.size), atol=1e-12
    )
    np.testing.assert_array_equal(run.substep_t[::5], run.t)
    f = s2_problem.vehicle.dynamics_function()
    for k in range(run.controls.shape[0]):
        current = run.currents[k]
        solution = solve_ivp(
            lambda _t, x, u=run.controls[k], c=current: np.array(f(x, u, c)).ravel(),
            (0.0, 0.1),
            run.states[k],
            method="DOP853",
            t_eval=0.02 * np.arange(1, 6),
            rtol=1e-12,
            atol=1e-12,
        )
        np.testing.assert_allclose(run.substep_states[5 * k + 1 : 5 * k + 6], solution.y.T, atol=1e-8)
    # a saved run keeps them; not recorded by default
    run.save(tmp_path / "run.npz")
    np.testing.assert_array_equal(
        uo.ClosedLoopResult.load(tmp_path / "run.npz").substep_states, run.substep_states
    )
    assert uo.simulate(uo.NMPC(s2_problem, "ipopt"), reference.initial_state(0.0), 0.2).substep_t.size == 0


class _FailingEveryThird(IpoptSolver):
    """IPOPT that reports failure on every third call (to exercise the fallback)."""

    name = "failing-ipopt"

    def __init__(self, problem, options=None):
        super().__init__(problem, options)
        self.calls = 0

    def solve(self, p, warm_start=None, rng=None, *, time_limit=None):  # time_limited, as IPOPT
        self.calls += 1
        if self.calls % 3 == 0:
            raise RuntimeError("synthetic solver crash")
        return super().solve(p, warm_start, rng, time_limit=time_limit)


class _InterruptedSecond(IpoptSolver):
    """Raises what CasADi raises when SIGINT arrives inside a plugin."""

    name = "interrupted-ipopt"

    def solve(self, p, warm_start=None, rng=None, *, time_limit=None):
        raise RuntimeError(
            "Error in Function::call for 'solver' [IpoptInterface] at .../casadi_interrupt.hpp: "
            "KeyboardInterrupt"
        )


def test_solver_crashes_never_stop_the_loop(s2_problem):
    REGISTRY.register("failing-ipopt", _FailingEveryThird, overwrite=True)
    try:
        controller = uo.NMPC(s2_problem.replace(), "failing-ipopt")
        run = uo.simulate(controller, s2_problem.reference.initial_state(0.0), 3.0)
        with pytest.raises(KeyboardInterrupt):  # an interrupt inside a backend is never swallowed
            REGISTRY.register("interrupted-ipopt", _InterruptedSecond, overwrite=True)
            uo.NMPC(s2_problem.replace(), "interrupted-ipopt").step(
                s2_problem.reference.initial_state(0.0), 0.0
            )
    finally:
        REGISTRY._factories.pop("failing-ipopt", None)
        REGISTRY._factories.pop("interrupted-ipopt", None)
    assert run.controls.shape[0] == 30
    # one call in three crashes (any 30 consecutive calls: 10, whatever the warm-up took), and
    # the backend's exception is recorded with its type and message on each of those steps
    crashed = [status == "exception: RuntimeError: synthetic solver crash" for status in run.statuses]
    assert sum(crashed) == 10
    assert np.all(run.fallback_steps[crashed])
    # fallback applies the next control of the previous plan
    assert np.all(np.isfinite(run.states))


def test_fallback_uses_the_shifted_previous_plan(s2_problem):
    controller = uo.NMPC(s2_problem, "ipopt")
    x0 = s2_problem.reference.initial_state(0.0)
    first = controller.step(x0, 0.0, np.zeros(3))
    plan = first.result.controls
    controller.backend = _AlwaysFails()
    second = controller.step(x0, 0.1, first.control)
    third = controller.step(x0, 0.2, second.control)
    assert second.fallback and third.fallback
    np.testing.assert_allclose(second.control, plan[1])
    np.testing.assert_allclose(third.control, plan[2])


class _AlwaysFails:
    def solve(self, p, warm_start=None, rng=None):
        raise RuntimeError("down")


def test_interrupt_returns_the_partial_run(s2_problem):
    class Interrupting(IpoptSolver):
        calls = 0

        def solve(self, p, warm_start=None, rng=None):
            Interrupting.calls += 1
            if Interrupting.calls == 6:
                raise KeyboardInterrupt
            return super().solve(p, warm_start, rng)

    controller = uo.NMPC(s2_problem, "ipopt")
    controller.backend = Interrupting(s2_problem)
    controller.warm_up(s2_problem.reference.initial_state(0.0))  # simulate then warms up no more
    Interrupting.calls = 0
    with pytest.raises(KeyboardInterrupt) as stop:  # Ctrl-C reaches the caller ...
        uo.simulate(controller, s2_problem.reference.initial_state(0.0), 2.0)
    run = stop.value.result  # ... with the five finished steps, marked as interrupted
    assert run.interrupted
    assert run.controls.shape[0] == 5 and run.states.shape[0] == 6


def test_current_mismatch_and_noise_run_and_save(tmp_path):
    reference = uo.Reference.paper("s2")
    problem = uo.TrackingProblem(uo.Vehicle.rexrov_controller_model(), reference, horizon=10)
    current = uo.Current(speed=0.3, direction=0.5, speed_noise=0.05, direction_noise=0.05)
    noise = uo.MeasurementNoise(std=(0.01, 0.01, 0.005, 0.01, 0.01, 0.005))

    def run_once():
        controller = uo.NMPC(problem, "ipopt")
        x0 = reference.initial_state(0.0)
        return uo.simulate(
            controller, x0, 3.0, current=current, noise=noise, plant=uo.Vehicle.rexrov(), seed=4
        )

    run, again = run_once(), run_once()
    np.testing.assert_array_equal(run.currents, again.currents)  # seeded
    assert np.all(np.isfinite(run.states))
    assert 0.2 < np.median(np.hypot(*run.currents.T)) < 0.4
    path = tmp_path / "run.npz"
    run.save(str(path))
    loaded = uo.ClosedLoopResult.load(str(path))
    np.testing.assert_array_equal(loaded.states, run.states)
    np.testing.assert_equal(loaded.metrics(), run.metrics())


# Gauss–Markov process of control/disturbances.py: s_{k+1} = s_k − μ (s_k − m) dt + σ √dt w_k,
# i.e. an AR(1) process s_{k+1} − m = φ (s_k − m) + σ √dt w_k with φ = 1 − μ dt.  Closed forms:
#   stationary mean m, stationary variance σ² dt / (1 − φ²), autocorrelation at lag k  φ^k.
GM_MEAN, GM_NOISE, GM_DECAY, GM_DT = 0.5, 1.0, 2.0, 0.1  # φ = 0.8, variance 0.1 / 0.36
GM_PHI = 1.0 - GM_DECAY * GM_DT
GM_VARIANCE = GM_NOISE**2 * GM_DT / (1.0 - GM_PHI**2)
GM_BURN_IN = 200  # the path starts at the mean: its variance is stationary up to φ^(2·200) ≈ 1e-39
GM_STEPS = 100_000


@pytest.fixture(scope="module")
def gauss_markov_path():
    # clamps 39 stationary standard deviations away from the mean: never active
    process = uo.GaussMarkov(mean=GM_MEAN, noise=GM_NOISE, decay=GM_DECAY, minimum=-20.0, maximum=21.0)
    path = process.sample(GM_STEPS, GM_DT, np.random.default_rng(11))
    assert path.shape == (GM_STEPS + 1,)
    return path[GM_BURN_IN:]


def test_gauss_markov_stationary_mean_and_variance_match_the_ar1_closed_form(gauss_markov_path):
    samples = gauss_markov_path
    n = samples.size
    # standard errors of an AR(1) sample of size n (large-n formulas):
    #   sample mean      sqrt(V/n · (1 + φ)/(1 − φ))
    #   sample variance  V · sqrt(2/n · (1 + φ²)/(1 − φ²))
    # tolerance 5 standard errors (false alarm < 1e-6 for a fixed seed that is either fine or not)
    mean_error = np.sqrt(GM_VARIANCE / n * (1 + GM_PHI) / (1 - GM_PHI))
    variance_error = GM_VARIANCE * np.sqrt(2.0 / n * (1 + GM_PHI**2) / (1 - GM_PHI**2))
    assert abs(samples.mean() - GM_MEAN) <= 5 * mean_error
    # 5 standard errors are 4.8 % of V: the exact-OU variance σ²/(2μ) (10 % lower) would fail
    assert abs(samples.var() - GM_VARIANCE) <= 5 * variance_error


@pytest.mark.parametrize("lag", [1, 2, 3, 5, 10])
def test_gauss_markov_autocorrelation_decays_as_one_minus_mu_dt_to_the_lag(gauss_markov_path, lag):
    samples = gauss_markov_path
    n = samples.size
    centred = samples - samples.mean()
    autocorrelation = np.dot(centred[:-lag], centred[lag:]) / np.dot(centred, centred)
    expected = GM_PHI**lag
    # Bartlett's formula for an AR(1) process:
    #   var(r_k) ≈ (1/n) [(1 + φ²)(1 − φ^(2k)) / (1 − φ²) − 2 k φ^(2k)]; tolerance 5 standard errors
    variance = (
        (1 + GM_PHI**2) * (1 - GM_PHI ** (2 * lag)) / (1 - GM_PHI**2) - 2 * lag * GM_PHI ** (2 * lag)
    ) / n
    assert abs(autocorrelation - expected) <= 5 * np.sqrt(variance)


def test_gauss_markov_clamps_to_its_bounds():
    process = uo.GaussMarkov(mean=0.5, noise=1.0, decay=0.5, minimum=0.0, maximum=1.0)
    samples = process.sample(5000, 0.1, np.random.default_rng(1))
    assert samples.min() == 0.0 and samples.max() == 1.0  # the bounds are reached, never crossed
    still = uo.GaussMarkov(mean=0.5, noise=0.0, decay=0.5).sample(10, 0.1, np.random.default_rng(0))
    np.testing.assert_array_equal(still, 0.5)


@pytest.mark.parametrize(
    ("kwargs", "name"),
    [
        ({"duration": 0.0}, "duration"),
        ({"duration": 1.0, "plant_substeps": 0}, "plant_substeps"),
        ({"duration": 1.0, "record_substeps": "yes"}, "record_substeps"),
    ],
)
def test_bad_simulation_arguments_raise(s2_problem, kwargs, name):
    with pytest.raises(ValueError, match=name):
        uo.simulate(uo.NMPC(s2_problem, "ipopt"), s2_problem.reference.initial_state(0.0), **kwargs)


def test_bad_current_raises():
    with pytest.raises(ValueError, match="speed"):
        uo.Current(speed=-0.1)


class _NoiseThatFails(uo.MeasurementNoise):
    """Zero noise, then NaN from the ``fail_at``-th measurement on (a broken sensor)."""

    def __init__(self, fail_at):
        super().__init__((0.0,) * 6)
        object.__setattr__(self, "fail_at", fail_at)
        object.__setattr__(self, "calls", [0])

    def sample(self, rng):
        self.calls[0] += 1
        return np.full(6, np.nan) if self.calls[0] > self.fail_at else np.zeros(6)


class _NoiseThatBlowsUp(_NoiseThatFails):
    def sample(self, rng):
        self.calls[0] += 1
        return np.full(6, 1e74) if self.calls[0] > self.fail_at else np.zeros(6)


def test_a_blown_up_measurement_ends_the_run_instead_of_raising():
    """A diverged estimate (finite, 1e74) is a fault like a NaN, not the controller's ValueError."""
    problem = uo.TrackingProblem(uo.Vehicle.rexrov(), uo.Reference.paper("s2"), horizon=8)
    x0 = problem.reference.initial_state(0.0)
    run = uo.simulate(uo.NMPC(problem, "sqp"), x0, 1.0, noise=_NoiseThatBlowsUp(4))
    assert run.fault is not None and "measurement beyond" in run.fault and "step 4" in run.fault
    assert run.controls.shape[0] == 4


def test_a_nan_measurement_ends_the_run_with_its_reason_and_keeps_what_came_before(tmp_path):
    problem = uo.TrackingProblem(uo.Vehicle.rexrov(), uo.Reference.paper("s2"), horizon=8)
    x0 = problem.reference.initial_state(0.0)
    clean = uo.simulate(uo.NMPC(problem, "sqp"), x0, 1.0)
    run = uo.simulate(uo.NMPC(problem, "sqp"), x0, 1.0, noise=_NoiseThatFails(4))
    assert run.fault is not None and "non-finite measurement" in run.fault and "step 4" in run.fault
    assert run.controls.shape[0] == 4 and run.states.shape[0] == 5
    # the recorded prefix is the run without the fault (zero noise is no noise)
    np.testing.assert_array_equal(run.states, clean.states[:5])
    np.testing.assert_array_equal(run.controls, clean.controls[:4])
    assert clean.fault is None
    path = tmp_path / "fault.npz"
    run.save(str(path))
    assert uo.ClosedLoopResult.load(str(path)).fault == run.fault


class _UnstablePlant:
    """A 3-DOF-shaped plant ẋ = λ x (λ = 50 1/s): it blows up whatever the controls."""

    # the VehicleModel protocol, with the 3-DOF vehicle's layout and bounds
    name, rate = "unstable", 50.0
    layout = uo.Vehicle.rexrov().layout
    control_bound = control_rate_bound = (1.0, 1.0, 1.0)

    def model_function(self):
        x, u, c = ca.SX.sym("x", 6), ca.SX.sym("u", 3), ca.SX.sym("c", 2)
        return ca.Function("unstable", [x, u, c], [self.rate * x])


def test_a_plant_that_blows_up_ends_the_run_at_the_last_finite_state():
    problem = uo.TrackingProblem(uo.Vehicle.rexrov(), uo.Reference.paper("s2"), horizon=8)
    x0 = problem.reference.initial_state(0.0) + 1.0  # away from zero, where ẋ = λx would stay
    run = uo.simulate(uo.NMPC(problem, "sqp"), x0, 2.0, plant=_UnstablePlant())
    assert run.fault is not None and "blew up" in run.fault
    # independent reference: RK4 of ẋ = λx over one 10 ms substep multiplies x by
    # 1 + z + z²/2 + z³/6 + z⁴/24 (z = λh); ten substeps per 0.1 s interval
    z = _UnstablePlant.rate * 0.01
    growth = (1 + z + z**2 / 2 + z**3 / 6 + z**4 / 24) ** 10
    expected = [x0 * growth**k for k in range(run.states.shape[0])]
    np.testing.assert_allclose(run.states, expected, rtol=1e-12)
    assert (
        np.max(np.abs(run.states[-1]))
        <= uo.control.simulation.BLOW_UP
        < np.max(np.abs(x0 * growth ** len(run.states)))
    )
    assert run.controls.shape[0] == run.states.shape[0] - 1


def test_metric_counts_are_integers():
    """Counts come out as int (issue 15), and they count what the run holds."""
    problem = uo.TrackingProblem(uo.Vehicle.rexrov(), uo.Reference.paper("s2"), horizon=5)
    run = uo.simulate(uo.NMPC(problem, "sqp"), problem.reference.initial_state(0.0), 0.5, progress=False)
    metrics = run.metrics()
    for key in ("failures", "relaxed_steps", "steps", "deadline_misses"):
        assert type(metrics[key]) is int, key
    assert metrics["steps"] == len(run.controls) == 5
    assert metrics["relaxed_steps"] == int(np.count_nonzero(run.relaxed_steps))


@pytest.mark.parametrize("hold", [None, 0.0], ids=["default-hold", "no-hold"])
def test_a_waypoint_mission_reaches_its_last_waypoint(hold):
    """The closed loop ends N dt before the reference: the mission's hold keeps the end inside."""
    points = [(0.0, 0.0), (4.0, 0.0), (4.0, 3.0)]
    extra = {} if hold is None else {"hold": hold}
    mission = uo.Reference.waypoints(points, 0.5, 1.0, name="mission", **extra)
    problem = uo.TrackingProblem(uo.Vehicle.rexrov(), mission, horizon=20, dt=0.1, terminal="cost")
    run = uo.simulate(uo.NMPC(problem, "ipopt"), mission.initial_state(0.0), problem.latest_start())
    miss = float(np.hypot(*(run.states[-1, :2] - np.asarray(points[-1]))))
    if hold is None:
        assert miss < 0.05 and np.hypot(*run.states[-1, 3:5]) < 0.05  # there, and at rest
    else:  # ending on arrival, the run stops N dt = 2 s (1 m at 0.5 m/s) short of it
        assert miss > 0.5
