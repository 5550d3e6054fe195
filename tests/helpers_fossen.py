"""Independent numpy references for the tests (no uuv_ocp code inside).

Fossen's 3-DOF model in matrix form, RK4, an adaptive high-order integrator, the analytic s2
reference and the cost of docs/formulation.md.  Nothing here calls uuv_ocp's dynamics,
integrators, rollouts or cost: only the vehicle's and the weights' *parameters* are read, so a
test comparing uuv_ocp with these functions compares two implementations.
"""

from __future__ import annotations

import numpy as np
from scipy.integrate import solve_ivp


# ---------------------------------------------------------------------------- model
def mass_matrix(vehicle) -> np.ndarray:
    """M = M_RB + M_A = diag(m + X_u̇, m + Y_v̇, I_z + N_ṙ) (Fossen 2011, diagonal case)."""
    added = np.asarray(vehicle.added_mass, dtype=float)
    return np.diag([vehicle.mass + added[0], vehicle.mass + added[1], vehicle.inertia + added[2]])


def coriolis_matrix(mass: np.ndarray, nu: np.ndarray) -> np.ndarray:
    """C(ν) of a diagonal M (Fossen 2011): [[0, 0, −M_y v], [0, 0, M_x u], [M_y v, −M_x u, 0]]."""
    m_x, m_y = mass[0, 0], mass[1, 1]
    u, v = nu[0], nu[1]
    return np.array([[0.0, 0.0, -m_y * v], [0.0, 0.0, m_x * u], [m_y * v, -m_x * u, 0.0]])


def damping_matrix(vehicle, nu: np.ndarray) -> np.ndarray:
    """D(ν) = diag(X_u + X_u|u| |u|, Y_v + Y_v|v| |v|, N_r + N_r|r| |r|)."""
    linear = np.asarray(vehicle.linear_damping, dtype=float)
    quadratic = np.asarray(vehicle.quadratic_damping, dtype=float)
    return np.diag(linear + quadratic * np.abs(nu))


def rotation(psi: float) -> np.ndarray:
    """R(ψ): body → inertial rotation about z (3×3, yaw rate passes through)."""
    c, s = np.cos(psi), np.sin(psi)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def fossen_rhs(vehicle, state, tau, current=(0.0, 0.0)) -> np.ndarray:
    """ẋ of ``[η, ν]`` with M ν̇_r + C(ν_r) ν_r + D(ν_r) ν_r = τ, ν_r = ν − ν_c, η̇ = R(ψ) ν.

    ``ν_c = R(ψ)ᵀ [V_x, V_y, 0]`` is the body-frame velocity of an irrotational, constant
    inertial current; it turns with the vehicle: ν̇_c = r [v_c, −u_c, 0].
    """
    state = np.asarray(state, dtype=float)
    eta, nu = state[:3], state[3:]
    mass = mass_matrix(vehicle)
    rot = rotation(eta[2])
    nu_c = rot.T @ np.array([current[0], current[1], 0.0])
    nu_r = nu - nu_c
    forces = np.asarray(tau, dtype=float) - coriolis_matrix(mass, nu_r) @ nu_r
    forces = forces - damping_matrix(vehicle, nu_r) @ nu_r
    nu_r_dot = np.linalg.solve(mass, forces)
    nu_c_dot = nu[2] * np.array([nu_c[1], -nu_c[0], 0.0])
    return np.concatenate([rot @ nu, nu_r_dot + nu_c_dot])


# ------------------------------------------------------------------------ integrators
def rk4(vehicle, state, tau, dt, current=(0.0, 0.0), substeps=1) -> np.ndarray:
    """Classical RK4 of :func:`fossen_rhs` over ``dt`` in ``substeps`` equal steps."""
    x = np.asarray(state, dtype=float)
    h = dt / substeps
    for _ in range(substeps):
        k1 = fossen_rhs(vehicle, x, tau, current)
        k2 = fossen_rhs(vehicle, x + h / 2 * k1, tau, current)
        k3 = fossen_rhs(vehicle, x + h / 2 * k2, tau, current)
        k4 = fossen_rhs(vehicle, x + h * k3, tau, current)
        x = x + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    return x


def rk4_rollout(vehicle, x0, controls, dt, currents=None, substeps=1) -> np.ndarray:
    """States (N+1, 6) under piecewise-constant ``controls`` (N, 3) with numpy RK4."""
    currents = (
        np.zeros((len(controls), 2)) if currents is None else np.broadcast_to(currents, (len(controls), 2))
    )
    states = [np.asarray(x0, dtype=float)]
    for tau, current in zip(controls, currents, strict=True):
        states.append(rk4(vehicle, states[-1], tau, dt, current, substeps))
    return np.array(states)


def exact_rollout(vehicle, x0, controls, dt, currents=None, tol=1e-12) -> np.ndarray:
    """States (N+1, 6) from scipy's DOP853 (rtol = atol = ``tol``) on each interval."""
    currents = (
        np.zeros((len(controls), 2)) if currents is None else np.broadcast_to(currents, (len(controls), 2))
    )
    states = [np.asarray(x0, dtype=float)]
    for tau, current in zip(controls, currents, strict=True):
        solution = solve_ivp(
            lambda _t, x, tau=tau, current=current: fossen_rhs(vehicle, x, tau, current),
            (0.0, dt),
            states[-1],
            method="DOP853",
            rtol=tol,
            atol=tol,
        )
        states.append(solution.y[:, -1])
    return np.array(states)


def rk4_error_bound(vehicle, x0, controls, dt, currents=None) -> np.ndarray:
    """Per-node bound on the global RK4 error at step ``dt`` (N+1, 6), by Richardson.

    For a fourth-order method ``x_h − x ≈ (16/15)(x_h − x_{h/2})``; the bound is ten times
    that estimate, element-wise (a safety factor for the non-smooth ``ν|ν|`` terms and for
    components whose estimate happens to be small; measured on s2: the true error is at most
    2.2 estimates), plus 1e-10 for rounding.  A wrong model term moves the states by 1e-4 or
    more over a horizon, against errors of 1e-6.
    """
    coarse = rk4_rollout(vehicle, x0, controls, dt, currents, substeps=1)
    fine = rk4_rollout(vehicle, x0, controls, dt, currents, substeps=2)
    return 10.0 * (16.0 / 15.0) * np.abs(coarse - fine) + 1e-10


# ------------------------------------------------------------------- reference (s2)
def s2_reference(times) -> np.ndarray:
    """States of the path x = 0.5 t, y = 2 sin(0.5 t) by the paper's Eq. (9), derivatives by hand.

    ψ_R = atan2(ẏ, ẋ), u_R = √(ẋ² + ẏ²), v_R = 0, r_R = (ẋÿ − ẏẍ)/(ẋ² + ẏ²); the heading is in
    (−π/2, π/2) on this path (ẋ > 0), so no unwrapping is needed.
    """
    t = np.asarray(times, dtype=float)
    xd, yd = 0.5 * np.ones_like(t), np.cos(0.5 * t)
    xdd, ydd = np.zeros_like(t), -0.5 * np.sin(0.5 * t)
    speed2 = xd**2 + yd**2
    return np.column_stack(
        [
            0.5 * t,
            2.0 * np.sin(0.5 * t),
            np.arctan2(yd, xd),
            np.sqrt(speed2),
            0 * t,
            (xd * ydd - yd * xdd) / speed2,
        ]
    )


# ------------------------------------------------------------------------------ cost
def formulation_cost(weights, states, scaled, scaled_prev, reference, terminal="equality") -> float:
    """Return the objective of docs/formulation.md (no tube), computed in numpy.

    Σ_{k=0}^{N−1} Σ_i S_i (z_k − z_{k−1})_i² + Σ_{k=1}^{N−1} ℓ(x_k, x_R,k) + V_N with
    ℓ = Σ w_i e_i², e = [e_x, e_y, 2 sin(e_ψ/2), e_u, e_v, e_r], w = [pose, velocity];
    V_N = 0 ("equality"), ℓ(x_N) ("none") or Σ terminal_i e_i² ("cost").
    """
    states, scaled, reference = (np.asarray(a, dtype=float) for a in (states, scaled, reference))
    previous = np.vstack([np.asarray(scaled_prev, dtype=float)[None, :], scaled[:-1]])
    cost = float(np.sum(np.asarray(weights.rate) * (scaled - previous) ** 2))
    error = states - reference
    error[:, 2] = 2.0 * np.sin(error[:, 2] / 2.0)
    node = np.concatenate([weights.pose, weights.velocity])
    cost += float(np.sum(node * error[1:-1] ** 2))
    if terminal == "none":
        cost += float(np.sum(node * error[-1] ** 2))
    elif terminal == "cost":
        cost += float(np.sum(np.asarray(weights.terminal) * error[-1] ** 2))
    return cost


def formulation_violation(
    states, scaled, scaled_prev, reference_final, rate_bound, terminal="equality"
) -> float:
    """Largest of: terminal residual (equality), |z| − 1 and |Δz| − Δz_max excess (≥ 0)."""
    scaled = np.asarray(scaled, dtype=float)
    previous = np.vstack([np.asarray(scaled_prev, dtype=float)[None, :], scaled[:-1]])
    parts = [np.max(np.maximum(0.0, np.abs(scaled) - 1.0))]
    parts.append(np.max(np.maximum(0.0, np.abs(scaled - previous) - np.asarray(rate_bound))))
    if terminal == "equality":
        residual = np.asarray(states[-1], dtype=float) - np.asarray(reference_final, dtype=float)
        residual[2] = np.remainder(residual[2] + np.pi, 2.0 * np.pi) - np.pi
        parts.append(np.max(np.abs(residual)))
    return float(max(parts))
