"""Small problems and sensors shared by the estimators' tests (linear, pendulum, compass, beacon)."""

import casadi as ca
import numpy as np

import uuv_ocp as uo
from uuv_ocp.estimation import Sensor, Sensors

DT = 0.1


A = np.array([[0.0, 1.0], [-1.0, -0.4]])


B = np.array([[0.0], [1.0]])


def linear_ocp() -> uo.Ocp:
    """``ẋ = A x + B u``: position and velocity of a damped spring, force input."""
    ocp = uo.Ocp(horizon=5, dt=DT)
    x = ocp.state("x", 2)
    u = ocp.control("u", 1, lower=-10.0, upper=10.0)
    ocp.set_der(x, ca.DM(A) @ x + ca.DM(B) @ u)
    ocp.add_stage_cost(residual=x, weight=(1.0, 1.0))
    return ocp


def rk4_linear(a: np.ndarray, b: np.ndarray, h: float) -> tuple[np.ndarray, np.ndarray]:
    """One RK4 step of ``ẋ = a x + b u`` (u held) as ``x⁺ = Φ x + Γ u``: its Taylor polynomial."""
    n = a.shape[0]
    ah = a * h
    phi = np.eye(n) + ah + ah @ ah / 2 + ah @ ah @ ah / 6 + ah @ ah @ ah @ ah / 24
    gamma = (np.eye(n) * h + ah * h / 2 + ah @ ah * h / 6 + ah @ ah @ ah * h / 24) @ b
    return phi, gamma


def linear_sensors() -> Sensors:
    return Sensors(
        [
            Sensor.of_states("position", [0], 2, 10.0, 0.1),
            Sensor.of_states("velocity", [1], 2, 5.0, 0.05, dropout=0.2),
        ]
    )


def pendulum_ocp() -> uo.Ocp:
    ocp = uo.Ocp(horizon=5, dt=DT)
    x = ocp.state("x", 2)
    u = ocp.control("u", 1, lower=-5.0, upper=5.0)
    ocp.set_der(x, ca.vertcat(x[1], -ca.sin(x[0]) - 0.2 * x[1] + u))
    ocp.add_stage_cost(residual=x, weight=(1.0, 1.0))
    return ocp


def pendulum_rk4(x: np.ndarray, u: float) -> np.ndarray:
    def f(s):
        return np.array([s[1], -np.sin(s[0]) - 0.2 * s[1] + u])

    k1 = f(x)
    k2 = f(x + DT / 2 * k1)
    k3 = f(x + DT / 2 * k2)
    k4 = f(x + DT * k3)
    return x + DT / 6 * (k1 + 2 * k2 + 2 * k3 + k4)


def compass_ocp(dt, rate_bound, std):
    """Return an Ocp of a heading ψ turned at a bounded rate and a compass reporting it in (−π, π]."""
    ocp = uo.Ocp(horizon=3, dt=dt)
    psi = ocp.state("psi", 1)
    r = ocp.control("r", 1, lower=-rate_bound, upper=rate_bound)
    ocp.set_der(psi, r)
    ocp.add_stage_cost(residual=psi, weight=1.0)
    compass = ca.Function("compass", [psi], [ca.atan2(ca.sin(psi), ca.cos(psi))])
    return ocp, uo.Sensors([uo.Sensor("heading", compass, 10.0, std, angular=(True,))])


def beacon_ocp():
    """Return a planar point moved by its velocity, a symbol of its position and its range to a beacon.

    The beacon is at the origin, where the range ``sqrt(x² + y²)`` has no Jacobian (0/0: NaN).
    """
    ocp = uo.Ocp(horizon=3, dt=DT)
    x = ocp.state("x", 2)
    u = ocp.control("u", 2, lower=-1.0, upper=1.0)
    ocp.set_der(x, u)
    ocp.add_stage_cost(residual=x, weight=(1.0, 1.0))
    at = ca.SX.sym("x", 2)
    return ocp, at, ca.Function("range", [at], [ca.sqrt(at[0] ** 2 + at[1] ** 2)])
