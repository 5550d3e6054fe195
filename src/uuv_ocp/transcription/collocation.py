"""Radau IIA collocation of one control interval: the equations and the implicit step they define.

On an interval of length ``h`` with the state ``x_k`` at its start and the control held, the
collocation polynomial of degree ``d`` passes through ``x_k`` and the collocation states
``K_1..K_d`` at the Radau points ``τ_1 < … < τ_d = 1`` (``casadi.collocation_points(d,
"radau")``) and satisfies the dynamics there:

    Σ_i C[i, j] Z_i = h f(K_j, u),  j = 1..d,   Z = [x_k, K_1, …, K_d],

with ``C`` the derivative matrix of the Lagrange basis (``casadi.collocation_coeff``).  The end
state is ``K_d`` (``τ_d = 1``).  This is the Radau IIA Runge–Kutta method: A-stable (L-stable),
of order ``2d − 1``; for ``x' = λx`` one step is the ``(d−1, d)`` Padé approximant of
``exp(hλ)``.

Direct collocation keeps ``K`` as NLP variables and the equations as stage constraints
(:func:`uuv_ocp.transcription.multiple_shooting.transcribe`); the condensed form (rollouts, the
swarms, the judge) solves them for ``K`` at each interval (:func:`implicit_step`), so both see
one discretisation: at a solution of the NLP, the rollout of its controls is its states.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import casadi as ca
import numpy as np

from uuv_ocp.transcription.base import register_transcription

if TYPE_CHECKING:
    from uuv_ocp.ocp import OcpSpec

#: Degrees of collocation offered (Radau IIA of order 1, 3, 5, 7, 9).
COLLOCATION_DEGREES = (1, 2, 3, 4, 5)
#: Newton iterations of the implicit step: the residual is at rounding after 3-6 on the
#: vehicles' intervals; the rest are a margin (a converged iteration changes nothing).
NEWTON_ITERATIONS = 30
#: Newton's absolute tolerance on the collocation residual (its units: the state's, times h).
NEWTON_TOLERANCE = 1e-13


def radau_points(degree: int) -> np.ndarray:
    """Radau IIA collocation points ``τ_1..τ_d`` in (0, 1], the last one 1."""
    return np.array(ca.collocation_points(degree, "radau"), dtype=float)


def collocation_residual(
    dynamics: ca.Function, dt: float, degree: int, name: str = "collocation"
) -> ca.Function:
    """Collocation equations of one interval, ``(K, x, u, p_stage, p_global) -> residual``.

    Parameters
    ----------
    dynamics : casadi.Function
        ``(x, u, p_stage, p_global) -> xdot``.
    dt : float
        Interval length h (s).
    degree : int
        Number of collocation points d (1..5).
    name : str
        Function name.

    Returns
    -------
    casadi.Function
        ``K`` is the collocation states stacked point after point, shape ``(d·nx,)``; the
        residual ``Σ_i C[i, j] Z_i − h f(K_j, u)`` stacked the same way (zero at a solution).
    """
    nx = dynamics.size1_in(0)
    coefficients, _, _ = ca.collocation_coeff(list(radau_points(degree)))
    derivative = np.array(coefficients)  # (d+1, d): column j gives the polynomial's slope at τ_j
    stacked = ca.SX.sym("K", degree * nx)
    x = ca.SX.sym("x", nx)
    u = ca.SX.sym("u", dynamics.size1_in(1))
    p_stage = ca.SX.sym("p_stage", dynamics.size1_in(2))
    p_global = ca.SX.sym("p_global", dynamics.size1_in(3))
    points = [x] + [stacked[j * nx : (j + 1) * nx] for j in range(degree)]
    residual = []
    for j in range(degree):
        slope = sum((float(derivative[i, j]) * points[i] for i in range(degree + 1)), ca.SX.zeros(nx))
        residual.append(slope - dt * dynamics(points[j + 1], u, p_stage, p_global))
    return ca.Function(
        name,
        [stacked, x, u, p_stage, p_global],
        [ca.vertcat(*residual)],
        ["K", "x", "u", "p_stage", "p_global"],
        ["residual"],
    )


def implicit_step(dynamics: ca.Function, dt: float, degree: int, name: str = "model_step") -> ca.Function:
    """One Radau IIA step ``(x, u, p_stage, p_global) -> x_next``, the collocation solved by Newton.

    The equations of :func:`collocation_residual` are solved for ``K`` by CasADi's
    ``fast_newton`` rootfinder (code-generable, so the compiled swarms and the generated C
    evaluate it too), started from ``K_j = x`` (the state held over the interval); its
    derivatives follow from the implicit function theorem.
    """
    residual = collocation_residual(dynamics, dt, degree, name=f"{name}_residual")
    nx = dynamics.size1_in(0)
    solver = ca.rootfinder(
        f"{name}_newton",
        "fast_newton",
        residual,
        {"max_iter": NEWTON_ITERATIONS, "abstol": NEWTON_TOLERANCE},
    )
    x = ca.SX.sym("x", nx)
    u = ca.SX.sym("u", dynamics.size1_in(1))
    p_stage = ca.SX.sym("p_stage", dynamics.size1_in(2))
    p_global = ca.SX.sym("p_global", dynamics.size1_in(3))
    stacked = solver(ca.repmat(x, degree, 1), x, u, p_stage, p_global)
    return ca.Function(
        name,
        [x, u, p_stage, p_global],
        [stacked[(degree - 1) * nx :]],
        ["x", "u", "p_stage", "p_global"],
        ["x_next"],
    )


class RadauCollocation:
    """Direct Radau IIA collocation of ``degree`` points per interval (module doc)."""

    name = "collocation"
    variable_kind = "K"
    row_kind = "collocation"

    def check_degree(self, degree: object, substeps: int) -> int:
        """Return the degree (3 by default); refuse one outside 1..5 or ``substeps`` other than 1."""
        if degree is None:
            degree = 3
        if isinstance(degree, bool) or degree not in COLLOCATION_DEGREES:
            raise ValueError(f"degree must be one of {list(COLLOCATION_DEGREES)}, got {degree!r}")
        if substeps != 1:
            raise ValueError(
                f"substeps must be 1 with transcription='collocation' (raise degree instead), got {substeps}"
            )
        return int(degree)

    def step(self, spec: OcpSpec) -> ca.Function:
        """Return the implicit Radau step (:func:`implicit_step`)."""
        return implicit_step(spec.dynamics, spec.dt, spec.degree, name="model_step")

    def interval_size(self, spec: OcpSpec) -> int:
        """``degree · nx`` collocation states."""
        return spec.degree * spec.state_dim

    def interval(
        self,
        spec: OcpSpec,
        step: ca.Function,
        variables: ca.SX,
        state: ca.SX,
        control: ca.SX,
        p_stage: ca.SX,
        p_global: ca.SX,
    ) -> tuple[ca.SX, ca.SX]:
        """Return the collocation equations and the last point (``τ_d = 1``) as the end state."""
        residual = collocation_residual(spec.dynamics, spec.dt, spec.degree)
        return residual(variables, state, control, p_stage, p_global), variables[-spec.state_dim :]

    def interval_guess(self, spec: OcpSpec, states: np.ndarray) -> np.ndarray:
        """Each collocation state on the chord from ``x_k`` to ``x_{k+1}``."""
        tau = radau_points(spec.degree)
        chords = states[:-1, None, :] + tau[None, :, None] * (states[1:] - states[:-1])[:, None, :]
        result: np.ndarray = chords.reshape(len(chords), -1)
        return result


register_transcription(RadauCollocation())
