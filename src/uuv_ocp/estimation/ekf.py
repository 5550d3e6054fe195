"""Extended Kalman filter on the augmented model (:mod:`uuv_ocp.estimation.base`).

Predict: ``x⁻ = f(x)``, ``P⁻ = F P Fᵀ + Q`` with ``F = ∂f/∂x`` by CasADi's AD; the prediction,
its covariance and the stacked sensor outputs and Jacobian at ``x⁻`` are one compiled Function
(one call per step).  Update, with only the rows of the sensors that reported (a variable-size
update): ``S = H P⁻ Hᵀ + R``, ``K = P⁻ Hᵀ S⁻¹``, ``x = x⁻ + K y`` and the Joseph form
``P = (I − K H) P⁻ (I − K H)ᵀ + K R Kᵀ``, which stays symmetric positive semi-definite under
rounding (Bucy and Joseph 1968; Simon, *Optimal State Estimation*, 2006, eq. 5.19).
"""

from __future__ import annotations

import casadi as ca
import numpy as np

from uuv_ocp.estimation.base import Estimator, buffered, register_estimator


class ExtendedKalmanFilter(Estimator):
    """EKF (module doc); build with ``uo.Estimator(problem, "ekf", sensors=...)``."""

    name = "ekf"

    def _build(self) -> None:
        m = self.model
        n = m.size
        P = ca.SX.sym("P", n, n)
        F = ca.jacobian(m.f, m.xa)
        predicted = ca.Function("ekf_f", m.inputs, [m.f])(*m.inputs)
        h_at = ca.Function("ekf_h", [m.xa], [m.h, ca.jacobian(m.h, m.xa)])
        # h and H at the predicted mean: substituted, so one call does predict and linearise
        h, H = h_at(predicted)
        self._predict = buffered("ekf_predict", [*m.inputs, P], [predicted, F @ P @ F.T + ca.DM(m.Q), h, H])
        self._measure = buffered("ekf_measure", [m.xa], list(h_at(m.xa)))
        self._h: np.ndarray | None = None
        self._H: np.ndarray | None = None
        self._identity = np.eye(n)

    def _reset_hook(self) -> None:
        self._h = self._H = None

    def predict(self, u: object) -> None:
        """``x⁻ = f(x, u)``, ``P⁻ = F P Fᵀ + Q`` (and the sensors linearised at ``x⁻``)."""
        m = self.model
        n = m.size
        x, P, h, H = self._predict(self.x, self._control(u), m.p_stage, m.p_global, self.P)
        self.x = x
        P = P.reshape(n, n, order="F")
        self.P = 0.5 * (P + P.T)
        self._h, self._H = h, H.reshape(h.size, n, order="F")
        self.steps += 1

    def _update(self, rows: np.ndarray, z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        if self._h is None or self._H is None:  # no prediction since the last update or reset
            h, H = self._measure(self.x)
            self._h, self._H = h, H.reshape(h.size, self.model.size, order="F")
        H = self._H[rows]
        R = self.R[rows]
        y = self._residual(rows, z, self._h[rows])
        PHt = self.P @ H.T
        S = H @ PHt + np.diag(R)
        K = np.linalg.solve(S, PHt.T).T  # S symmetric: K = P Hᵀ S⁻¹
        self.x = self.x + K @ y
        A = self._identity - K @ H
        P = A @ self.P @ A.T + (K * R) @ K.T
        self.P = 0.5 * (P + P.T)
        self._h = self._H = None  # linearised at the prior: stale after the update
        return y, S


register_estimator("ekf", ExtendedKalmanFilter)
