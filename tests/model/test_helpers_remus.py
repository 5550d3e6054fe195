"""Self-tests of the independent REMUS 100 reference (tests/helpers_remus.py).

Each test checks the reference against something computed here from the published constants
or from textbook identities (Lamb's integrals, Fossen's M_RB about the CO, the zyx Euler
kinematics of scipy's Rotation), not against the reference's own outputs.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.integrate import quad, solve_ivp
from scipy.optimize import brentq
from scipy.spatial.transform import Rotation

from tests.helpers_remus import (
    DIAMETER,
    FIN_AREA,
    GRAVITY,
    LENGTH,
    MAX_FIN,
    MAX_RPM,
    RHO,
    STEADY_RPM,
    STEADY_SPEED,
    STEADY_SPEED_QUOTE,
    remus100_derivative,
    remus100_matrices,
    remus100_steady_speed,
)

A, B = LENGTH / 2.0, DIAMETER / 2.0  # spheroid semi-axes (m), remus100.py `a`, `b`
Z_G = 0.02  # CG below the CO (m), remus100.py `r_bg = [0, 0, 0.02]`


def _published_mass() -> float:
    """Mass m = 4/3 π ρ a b² (kg), remus100.py: "mass of spheriod"."""
    return 4.0 / 3.0 * math.pi * RHO * A * B**2


def _propeller(n_rpm: float, speed: float) -> tuple[float, float]:
    """(0.9 X_prop, K_prop/10) at n > 0 from remus100.py's K_T, K_Q lines (N, N·m)."""
    n = n_rpm / 60.0
    j_a = 0.944 * speed / (n * 0.14)  # advance number J_a = V_a / (n D)
    k_t = 0.4566 + (0.1798 - 0.4566) / 0.6632 * j_a
    k_q = 0.0700 + (0.0312 - 0.0700) / 0.6632 * j_a
    return 0.9 * RHO * n**2 * 0.14**4 * k_t, RHO * n**2 * 0.14**5 * k_q / 10.0


def _state(nu=(0.0,) * 6, eta=(0.0,) * 6) -> np.ndarray:
    return np.concatenate([np.asarray(nu, dtype=float), np.asarray(eta, dtype=float)])


# ------------------------------------------------------------------------ matrices
def test_rigid_body_mass_about_the_co_is_fossens():
    # Fossen (2021) Eq. (3.44) with r_g = [0, 0, z_g]: M_RB = [[m I, −m S(r_g)], [m S(r_g), I_o]]
    # with I_o = diag(I_x + m z_g², I_y + m z_g², I_z); written out entry by entry.
    m = _published_mass()
    i_x, i_y = 0.4 * m * B**2, 0.2 * m * (A**2 + B**2)
    expected = np.diag([m, m, m, i_x + m * Z_G**2, i_y + m * Z_G**2, i_y])
    expected[0, 4] = expected[4, 0] = m * Z_G
    expected[1, 3] = expected[3, 1] = -m * Z_G
    np.testing.assert_allclose(remus100_matrices().m_rb, expected, rtol=1e-14, atol=1e-14)


def test_added_mass_is_lambs_from_the_defining_integrals():
    # Lamb (1932) §373: α_0 = a b² ∫ dλ / ((a²+λ)^{3/2} (b²+λ)), β_0 = a b² ∫ dλ / ((a²+λ)^{1/2}
    # (b²+λ)²) over [0, ∞); k_1 = α_0/(2 − α_0), k_2 = β_0/(2 − β_0).  Integrated numerically here,
    # in closed form in the source (an older remus100.py had a misplaced bracket in β_0).
    alpha_0 = A * B**2 * quad(lambda s: 1.0 / ((A**2 + s) ** 1.5 * (B**2 + s)), 0.0, np.inf)[0]
    beta_0 = A * B**2 * quad(lambda s: 1.0 / ((A**2 + s) ** 0.5 * (B**2 + s) ** 2), 0.0, np.inf)[0]
    m = _published_mass()
    added = np.diag(remus100_matrices().m_a)
    np.testing.assert_allclose(added[0], m * alpha_0 / (2.0 - alpha_0), rtol=1e-9)
    np.testing.assert_allclose(added[1:3], m * beta_0 / (2.0 - beta_0), rtol=1e-9)
    np.testing.assert_allclose(added[3], 0.3 * 0.4 * m * B**2, rtol=1e-14)  # A44 = 0.3 I_x


# ------------------------------------------------------------------------- at rest
def test_at_rest_only_the_restoring_moments_act():
    # W = m g and B = W as in remus100.py; g(η) of Fossen (2021) Eq. (4.6) for r_bg = [0, 0, z_g],
    # r_bb = 0: only K = W z_g cosθ sinφ and M = W z_g sinθ survive.  At rest the fins and the
    # stopped propeller give nothing (U = 0), so M ν̇ = −g(η).
    rng = np.random.default_rng(20261203)
    mats = remus100_matrices()
    weight = _published_mass() * GRAVITY
    buoyancy = weight
    for _ in range(20):
        phi, theta = rng.uniform(-0.6, 0.6, size=2)
        psi = rng.uniform(-np.pi, np.pi)
        fins = rng.uniform(-MAX_FIN, MAX_FIN, size=2)
        x = _state(eta=(*rng.normal(size=3), phi, theta, psi))
        nu_dot = remus100_derivative(x, [*fins, 0.0])[:6]
        expected = np.zeros(6)
        expected[2] = -(weight - buoyancy) * math.cos(theta) * math.cos(phi)
        expected[3] = weight * Z_G * math.cos(theta) * math.sin(phi)
        expected[4] = weight * Z_G * math.sin(theta)
        np.testing.assert_allclose(mats.m_total @ nu_dot, -expected, rtol=1e-12, atol=1e-12)
        assert nu_dot[2] == 0.0  # neutral buoyancy, heave decoupled in M: no sinking
        assert np.sign(nu_dot[4]) == -np.sign(theta) and np.sign(nu_dot[3]) == -np.sign(phi)
        np.testing.assert_allclose(remus100_derivative(x, [*fins, 0.0])[6:], 0.0, atol=0.0)


# ------------------------------------------------------------------ hydrodynamics
def test_pure_sway_meets_cross_flow_and_axial_drag():
    # ν = [0, v, 0, 0, 0, 0]: gnc.py crossFlowDrag sums −½ ρ T C_D,2D |v| v dx over the 21 stations
    # x = −L/2, …, L/2 with dx = L/20 (so over 1.05 L), T = D = 0.19 m; C_D,2D by linear
    # interpolation of Hoerner's table at B/2T = 0.5 between (0.4933, 1.2108) and (0.5585, 1.0836).
    # forceLiftDrag takes α = atan2(0, 0) = 0, so the *axial* drag ½ ρ U_r² S CD_0 acts in surge
    # although the flow is sideways (as in the source).  Linear sway damping M_22/20 e^{−3|v|}.
    mats = remus100_matrices()
    cd_2d = 1.2108 + (0.5 - 0.4933) / (0.5585 - 0.4933) * (1.0836 - 1.2108)
    area = 0.7 * LENGTH * DIAMETER
    cd_0 = 0.42 * math.pi * B**2 / area
    for v in (-0.7, -0.2, 0.05, 0.4, 1.1):
        forces = mats.m_total @ remus100_derivative(_state(nu=(0, v, 0, 0, 0, 0)), [0, 0, 0])[:6]
        sway = -0.5 * RHO * DIAMETER * cd_2d * abs(v) * v * 21 * LENGTH / 20
        sway -= mats.m_total[1, 1] / 20.0 * math.exp(-3.0 * abs(v)) * v
        expected = np.array([-0.5 * RHO * v**2 * area * cd_0, sway, 0, 0, 0, 0])
        np.testing.assert_allclose(forces, expected, rtol=1e-12, atol=1e-12)


def test_hull_lift_and_drag_from_the_angle_of_attack():
    # ν = [u, 0, w, 0, 0, 0]: Beard-McLain wing of gnc.py forceLiftDrag with span D and area S:
    # AR = D²/S, CL = π AR / (1 + √(1 + (AR/2)²)) α, CD = CD_0 + CL²/(π 0.7 AR), rotated by
    # α = atan2(w, u).  The added-mass Munk moment in pitch, m (k_2 − k_1) u w, is one of the C_A
    # terms the source zeroes, so no pitch moment appears.  Linear damping M_11/20 e^{−3U_r},
    # M_33/20 (heave has no speed factor).
    rng = np.random.default_rng(13)
    mats = remus100_matrices()
    area = 0.7 * LENGTH * DIAMETER
    aspect = DIAMETER**2 / area
    cd_0 = 0.42 * math.pi * B**2 / area
    for _ in range(10):
        u, w = rng.uniform(0.2, 2.5), rng.uniform(-0.5, 0.5)
        forces = mats.m_total @ remus100_derivative(_state(nu=(u, 0, w, 0, 0, 0)), [0, 0, 0])[:6]
        alpha, speed2 = math.atan2(w, u), u**2 + w**2
        cl = math.pi * aspect / (1.0 + math.sqrt(1.0 + (aspect / 2.0) ** 2)) * alpha
        cd = cd_0 + cl**2 / (math.pi * 0.7 * aspect)
        lift, drag = 0.5 * RHO * speed2 * area * cl, 0.5 * RHO * speed2 * area * cd
        surge = -drag * math.cos(alpha) + lift * math.sin(alpha)
        surge -= mats.m_total[0, 0] / 20.0 * math.exp(-3.0 * math.sqrt(speed2)) * u
        heave = -drag * math.sin(alpha) - lift * math.cos(alpha) - mats.m_total[2, 2] / 20.0 * w
        np.testing.assert_allclose(forces, [surge, 0, heave, 0, 0, 0], rtol=1e-12, atol=1e-12)


# -------------------------------------------------------------------- symmetries
def test_rudder_moment_is_odd_and_as_published():
    # On a straight run (v = r = 0, p = q = 0) the yaw row of M is decoupled and only the rudder
    # acts in yaw: ṙ = x_r Y_r / M_66, Y_r = −½ ρ U_rh² A_r CL_r δ_r, x_r = −L/2 (remus100.py).
    rng = np.random.default_rng(7)
    m66 = remus100_matrices().m_total[5, 5]
    for _ in range(20):
        u = rng.uniform(0.3, 2.5)
        n = rng.uniform(0.0, MAX_RPM)
        delta = rng.uniform(0.01, MAX_FIN)
        x = _state(nu=(u, 0, 0, 0, 0, 0), eta=(0, 0, 5.0, 0, 0, rng.uniform(-3, 3)))
        plus = remus100_derivative(x, [delta, 0.0, n])
        minus = remus100_derivative(x, [-delta, 0.0, n])
        y_r = -0.5 * RHO * u**2 * 2.0 * FIN_AREA * 0.5 * delta
        np.testing.assert_allclose(plus[5], (-LENGTH / 2.0) * y_r / m66, rtol=1e-12)
        np.testing.assert_allclose(plus[5], -minus[5], rtol=1e-12)
        assert plus[5] > 0.0  # source convention: δ_r > 0 gives N > 0 (x_r < 0, Y_r < 0)


def test_stern_plane_pitch_moment_is_odd():
    # The surge-pitch coupling of M (m z_g) mixes the even fin drag X_s into q̇, so the odd part
    # is checked on the generalised force M ν̇: pitch moment −x_s Z_s, Z_s ∝ δ_s (remus100.py).
    rng = np.random.default_rng(11)
    mats = remus100_matrices()
    for _ in range(20):
        u, n, delta = rng.uniform(0.3, 2.5), rng.uniform(0.0, MAX_RPM), rng.uniform(0.01, MAX_FIN)
        x = _state(nu=(u, 0, 0, 0, 0, 0), eta=(0, 0, 5.0, 0, 0, 0))
        forces = [mats.m_total @ remus100_derivative(x, [0.0, s, n])[:6] for s in (delta, 0.0, -delta)]
        z_s = -0.5 * RHO * u**2 * 2.0 * FIN_AREA * 0.7 * delta
        np.testing.assert_allclose(forces[0][4] - forces[1][4], (LENGTH / 2.0) * z_s, rtol=1e-10)
        np.testing.assert_allclose(forces[0][4] - forces[1][4], forces[1][4] - forces[2][4], rtol=1e-10)
        assert forces[0][4] < forces[1][4]  # δ_s > 0: Z_s < 0 and nose down (MSS 2024-06-23 note)


def _straight_run(x0, n_rpm, t_end):
    return solve_ivp(
        lambda _t, y: remus100_derivative(y, [0.0, 0.0, n_rpm]),
        (0.0, t_end),
        x0,
        method="DOP853",
        rtol=1e-10,
        atol=1e-12,
    ).y


def test_coasting_straight_run_stays_in_the_vertical_plane():
    # Zero fins and a stopped propeller: nothing acts in sway, roll or yaw and the hull is
    # port-starboard symmetric, so v, p, r and φ stay exactly zero and ψ keeps its value.  (The
    # vertical plane does move: M_15 = m z_g couples the decelerating surge into pitch.)
    y = _straight_run(_state(nu=(2.0, 0, 0, 0, 0, 0), eta=(0, 0, 10.0, 0, 0, 0.3)), 0.0, 30.0)
    np.testing.assert_allclose(y[[1, 3, 5, 9]], 0.0, atol=1e-15)  # v, p, r, φ
    np.testing.assert_allclose(y[11], 0.3, atol=1e-15)  # ψ
    np.testing.assert_allclose(np.arctan2(np.diff(y[7]), np.diff(y[6])), 0.3, atol=1e-12)  # track
    assert np.all(np.diff(y[0]) < 0.0) and y[0, -1] > 0.0


def test_propelled_straight_run_settles_heeled_to_the_propeller_torque():
    # With the propeller turning, K_prop/10 rolls the vehicle; the settled heel balances it against
    # the bottom-heaviness: W z_g sin φ = K_prop/10 at the settled speed.  During the start the
    # roll couples into sway (M_24 = −m z_g) and yaw (C_RB: m z_g u p) and the surge acceleration
    # into pitch (M_15 = m z_g), so v, r, ψ, w, q, θ are *not* zero throughout in the source's
    # model (ψ ends 8e-4 rad off, z 0.64 m deeper); the rates settle to zero.
    y = _straight_run(_state(eta=(0, 0, 10.0, 0, 0, 0)), STEADY_RPM, 150.0)
    np.testing.assert_allclose(y[[2, 3, 4, 5, 10], -1], 0.0, atol=1e-8)  # w, p, q, r, θ
    u_end, phi_end = y[0, -1], y[9, -1]
    _, roll_torque = _propeller(STEADY_RPM, u_end)
    weight = _published_mass() * GRAVITY
    # 5e-6 relative is left by the slowly decaying sway (v ≈ 5e-4 m/s, v̇ ≈ −1e-6 m/s², lightly
    # damped at speed) acting in roll through M_42 = −m z_g.
    np.testing.assert_allclose(math.sin(phi_end), roll_torque / (weight * Z_G), rtol=5e-5)


# --------------------------------------------------------------- current and frames
def test_current_enters_the_kinetics_only_through_the_relative_velocity():
    # With the propeller stopped (its advance speed is the only use of the absolute speed), the
    # kinetics are those of ν_r = ν − ν_c plus ν̇_c = [r v_c, −r u_c, 0, 0, 0, 0]; the kinematics
    # use the absolute ν.  ν_c = [V_c cos(β_c − ψ), V_c sin(β_c − ψ), 0, 0, 0, 0] (remus100.py).
    rng = np.random.default_rng(3)
    for _ in range(20):
        nu = np.concatenate([rng.uniform(-1.0, 2.0, 3), rng.uniform(-0.3, 0.3, 3)])
        eta = np.concatenate([rng.normal(size=3), rng.uniform(-0.5, 0.5, 2), [rng.uniform(-3, 3)]])
        fins = rng.uniform(-MAX_FIN, MAX_FIN, 2)
        v_c, beta_c = rng.uniform(0.0, 0.5), rng.uniform(-np.pi, np.pi)
        u_c, w_c = v_c * math.cos(beta_c - eta[5]), v_c * math.sin(beta_c - eta[5])
        nu_r = nu - np.array([u_c, w_c, 0, 0, 0, 0])
        with_current = remus100_derivative(_state(nu, eta), [*fins, 0.0], (v_c, beta_c))
        relative = remus100_derivative(_state(nu_r, eta), [*fins, 0.0])
        expected = relative[:6] + np.array([nu[5] * w_c, -nu[5] * u_c, 0, 0, 0, 0])
        np.testing.assert_allclose(with_current[:6], expected, rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(with_current[6:], remus100_derivative(_state(nu, eta), [*fins, 0])[6:])


def test_kinematics_are_the_zyx_euler_ones():
    # ṗ = R(Θ) v with R from scipy's intrinsic 'ZYX' rotation (ψ, θ, φ); ω_b = T⁻¹(Θ) Θ̇ with
    # T⁻¹ = [[1, 0, −sθ], [0, cφ, cθ sφ], [0, −sφ, cθ cφ]] (Fossen 2021, Eq. 2.28).
    rng = np.random.default_rng(5)
    for _ in range(20):
        nu = rng.normal(size=6)
        phi, theta, psi = rng.uniform(-1.2, 1.2), rng.uniform(-1.2, 1.2), rng.uniform(-3, 3)
        eta_dot = remus100_derivative(_state(nu, (0, 0, 0, phi, theta, psi)), [0, 0, 0])[6:]
        rot = Rotation.from_euler("ZYX", [psi, theta, phi]).as_matrix()
        np.testing.assert_allclose(eta_dot[:3], rot @ nu[:3], rtol=1e-12, atol=1e-12)
        t_inv = np.array(
            [
                [1.0, 0.0, -math.sin(theta)],
                [0.0, math.cos(phi), math.cos(theta) * math.sin(phi)],
                [0.0, -math.sin(phi), math.cos(theta) * math.cos(phi)],
            ]
        )
        np.testing.assert_allclose(t_inv @ eta_dot[3:], nu[3:], rtol=1e-12, atol=1e-12)


def test_actuators_saturate_as_in_the_source():
    x = _state(nu=(1.5, 0.1, -0.05, 0.01, 0.02, -0.03), eta=(0, 0, 5, 0.1, -0.1, 1.0))
    np.testing.assert_array_equal(
        remus100_derivative(x, [1.0, -1.0, 3000.0]), remus100_derivative(x, [MAX_FIN, -MAX_FIN, MAX_RPM])
    )
    assert MAX_FIN == pytest.approx(math.radians(15.0)) and MAX_RPM == 1525.0


@pytest.mark.parametrize(
    ("args", "name"),
    [
        ((np.zeros(11), [0, 0, 0]), "state"),
        ((np.zeros(12), [0, 0]), "actuators"),
        ((np.zeros(12), [0, 0, 0], (0.1,)), "current"),
        ((np.full(12, np.nan), [0, 0, 0]), "state"),
    ],
)
def test_bad_inputs_name_the_parameter(args, name):
    with pytest.raises(ValueError, match=name):
        remus100_derivative(*args)


# ------------------------------------------------------------------- steady speed
def test_steady_speed_is_the_surge_balance_and_near_the_published_speed():
    # Published (remus100.py docstring): STEADY_SPEED_QUOTE = "The maximum speed of 2.5 m/s is
    # obtained when the propeller runs at 1525 rpm in zero currents."
    #
    # The independent check: on the settled straight run the surge equation is
    # (1 − t) X_prop(U) = ½ ρ U² S CD_0 + (M_11/T_surge) e^{−3U} U, with CD_0 = 0.42 π b²/S and
    # S = 0.7 L D (remus100.py); solved here with brentq.  It gives 2.5536 m/s, 2.15 % above the
    # stated 2.5 m/s: the source's own model does not meet a 2 % band, so the band here is 2.5 %
    # (MSS remus100.m of 2025, which scales a and b by 1.0096 to get m = 31.9 kg, gives 2.540).
    assert "2.5 m/s" in STEADY_SPEED_QUOTE and "1525 rpm" in STEADY_SPEED_QUOTE
    area = 0.7 * LENGTH * DIAMETER
    cd_0 = 0.42 * math.pi * B**2 / area
    d_11 = remus100_matrices().m_total[0, 0] / 20.0

    def surge(speed):
        return (
            _propeller(STEADY_RPM, speed)[0]
            - 0.5 * RHO * speed**2 * area * cd_0
            - d_11 * math.exp(-3.0 * speed) * speed
        )

    balance = brentq(surge, 0.5, 5.0, xtol=1e-14)
    speed = remus100_steady_speed(STEADY_RPM)
    np.testing.assert_allclose(speed, balance, rtol=1e-7)
    assert abs(speed - STEADY_SPEED) / STEADY_SPEED < 0.025
