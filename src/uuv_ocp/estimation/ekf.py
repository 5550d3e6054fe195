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

from uuv_ocp.estimation.base import Estimate, Estimator, buffered, register_estimator
from uuv_ocp.estimation.sensors import Measurement
from uuv_ocp.native.buffered import BufferedFunction
from uuv_ocp.native.compile import default_cache_directory, load_or_fallback


class ExtendedKalmanFilter(Estimator):
    """EKF (module doc); build with ``uo.Estimator(problem, "ekf", sensors=...)``."""

    name = "ekf"
    compiles = True

    def _build(self) -> None:
        m = self.model
        n = m.size
        P = ca.SX.sym("P", n, n)
        F = ca.jacobian(m.f, m.xa)
        predicted = ca.Function("ekf_f", m.inputs, [m.f])(*m.inputs)
        h_at = ca.Function("ekf_h", [m.xa], [m.h, ca.jacobian(m.h, m.xa)])
        # h and H at the predicted mean: substituted, so one call does predict and linearise
        h, H = h_at(predicted)
        # the process noise's diagonal is an input, not a constant: the compiled step (minutes
        # of C compiler on a 6-DOF vehicle) serves every noise setting from its disk cache
        q = ca.SX.sym("q", n)
        self._q = np.diag(m.Q).copy()
        covariance = F @ P @ F.T + ca.diag(q)
        self._predict = buffered("ekf_predict", [*m.inputs, P, q], [predicted, covariance, h, H])
        self._measure = buffered("ekf_measure", [m.xa], list(h_at(m.xa)))
        self._h: np.ndarray | None = None
        self._H: np.ndarray | None = None
        self._identity = np.eye(n)
        self._fused = self._fused_step(P, q, predicted, 0.5 * (covariance + covariance.T), h, H)
        self._z = np.zeros(self.R.size)
        self._mask = np.zeros(self.R.size)

    def _fused_step(
        self, P: ca.SX, q: ca.SX, predicted: ca.SX, covariance: ca.SX, h: ca.SX, H: ca.SX
    ) -> BufferedFunction:
        """Return the one-call predict-and-update for every combination of reporting sensors.

        The same arithmetic as :meth:`predict` then :meth:`correct`, on all the stacked outputs
        with a 0/1 ``mask``: a row that did not report has its ``H`` row and innovation zeroed
        and unit variance, so ``S`` is block-diagonal in it and its gain column is zero (the
        update is the one of the reporting rows alone, to rounding).  One Function, built and,
        where a C compiler exists, compiled here, so no step builds anything; the solve is
        CasADi's symbolic QR (LAPACK's LU in :meth:`correct`: equal to rounding).
        """
        m = self.model
        outputs = len(self.R)
        z, mask = ca.SX.sym("z", outputs), ca.SX.sym("mask", outputs)
        y = z - h
        for row in np.flatnonzero(self.angular):  # angles: the innovation wrapped into (−π, π]
            y[int(row)] = ca.atan2(ca.sin(y[int(row)]), ca.cos(y[int(row)]))
        # if_else, not a product: a row that did not report may be NaN or Inf where its sensor
        # is undefined (a range at its beacon), and 0 · NaN is NaN
        y = ca.if_else(mask, y, 0)
        Hm = ca.if_else(ca.repmat(mask, 1, m.size), H, 0)
        R = ca.diag(mask * ca.DM(self.R) + (1 - mask))
        PHt = covariance @ Hm.T
        S = Hm @ PHt + R
        K = ca.solve(S, PHt.T).T
        A = ca.DM.eye(m.size) - K @ Hm
        updated = A @ covariance @ A.T + K @ R @ K.T
        fused = ca.Function(
            "uuv_ocp_ekf_step",
            [*m.inputs, P, q, z, mask],
            [ca.densify(o) for o in (predicted + K @ y, 0.5 * (updated + updated.T), y, S)],
        )
        if self.compiled:
            loaded, library = load_or_fallback([fused], default_cache_directory(), name="uuv_ocp_ekf")
            fused, self.compiled = loaded[fused.name()], library is not None
        return BufferedFunction(fused)

    def step(self, u: object, measurement: Measurement) -> Estimate:
        """:meth:`predict` under ``u`` and :meth:`correct` with ``measurement``, in one CasADi call."""
        rows = self.measured_rows(measurement)
        if not rows.size:
            self.predict(u)
            return self.estimate(measurement.step)
        m = self.model
        n = m.size
        z, mask = self._z, self._mask
        z.fill(0.0)
        mask.fill(0.0)
        z[rows], mask[rows] = measurement.values, 1.0
        x, P, y, S = self._fused(self.x, self._control(u), m.p_stage, m.p_global, self.P, self._q, z, mask)
        self.x, self.P = x, P.reshape(n, n, order="F")
        self._h = self._H = None
        self.steps += 1
        S = S.reshape(z.size, z.size, order="F")[np.ix_(rows, rows)]
        return self.estimate(measurement.step, measurement.sensors, y[rows], S)

    def _reset_hook(self) -> None:
        self._h = self._H = None

    def predict(self, u: object) -> None:
        """``x⁻ = f(x, u)``, ``P⁻ = F P Fᵀ + Q`` (and the sensors linearised at ``x⁻``)."""
        m = self.model
        n = m.size
        x, P, h, H = self._predict(self.x, self._control(u), m.p_stage, m.p_global, self.P, self._q)
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
