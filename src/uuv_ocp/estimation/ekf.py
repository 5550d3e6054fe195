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

from uuv_ocp._concurrency import BUILD_LOCK
from uuv_ocp.estimation.base import Estimate, Estimator, buffered, register_estimator
from uuv_ocp.estimation.sensors import Measurement
from uuv_ocp.native.buffered import BufferedFunction


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
        covariance = F @ P @ F.T + ca.DM(m.Q)
        self._predict = buffered("ekf_predict", [*m.inputs, P], [predicted, covariance, h, H])
        # what a fused step (predict and update in one call, per combination of sensors) uses
        self._symbols = (P, predicted, 0.5 * (covariance + covariance.T), h, H)
        self._fused: dict[tuple[int, ...], BufferedFunction] = {}
        self._measure = buffered("ekf_measure", [m.xa], list(h_at(m.xa)))
        self._h: np.ndarray | None = None
        self._H: np.ndarray | None = None
        self._identity = np.eye(n)

    def _fused_step(self, sensors: tuple[int, ...]) -> BufferedFunction:
        """Return the one-call predict-and-update of a combination of reporting sensors.

        The same arithmetic as :meth:`predict` then :meth:`correct` (the update's solve is
        CasADi's symbolic QR instead of LAPACK's LU: equal to rounding); built on first use of
        the combination (a schedule has a handful).
        """
        fused = self._fused.get(sensors)
        if fused is not None:
            return fused
        m = self.model
        rows = self.rows(sensors).tolist()
        P, predicted, covariance, h, H = self._symbols
        with BUILD_LOCK:  # CasADi expressions are built here
            z = ca.SX.sym("z", len(rows))
            y = z - h[rows]
            for i, row in enumerate(rows):  # angles: the innovation wrapped into (−π, π]
                if self.angular[row]:
                    y[i] = ca.atan2(ca.sin(y[i]), ca.cos(y[i]))
            Hr = H[rows, :]
            R = ca.diag(ca.DM(self.R[rows]))
            PHt = covariance @ Hr.T
            S = Hr @ PHt + R
            K = ca.solve(S, PHt.T).T
            A = ca.DM.eye(m.size) - K @ Hr
            updated = A @ covariance @ A.T + K @ R @ K.T
            outputs = [predicted + K @ y, 0.5 * (updated + updated.T), y, S]
        fused = self._fused[sensors] = buffered("ekf_step", [*m.inputs, P, z], outputs)
        return fused

    def step(self, u: object, measurement: Measurement) -> Estimate:
        """:meth:`predict` under ``u`` and :meth:`correct` with ``measurement``, in one CasADi call."""
        rows = self.measured_rows(measurement)
        if not rows.size:
            self.predict(u)
            return self.estimate(measurement.step)
        m = self.model
        n, size = m.size, rows.size
        x, P, y, S = self._fused_step(measurement.sensors)(
            self.x, self._control(u), m.p_stage, m.p_global, self.P, measurement.values
        )
        self.x, self.P = x, P.reshape(n, n, order="F")
        self._h = self._H = None
        self.steps += 1
        return self.estimate(measurement.step, measurement.sensors, y, S.reshape(size, size, order="F"))

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
