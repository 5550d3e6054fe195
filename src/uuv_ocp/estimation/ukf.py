"""Unscented Kalman filter on the augmented model (:mod:`uuv_ocp.estimation.base`).

Merwe's scaled sigma points (van der Merwe, *Sigma-Point Kalman Filters*, 2004): with
``n`` augmented states, ``λ = α² (n + κ) − n`` and ``L Lᵀ = (n + λ) P`` (Cholesky), the points
are ``x``, ``x + L[:, i]``, ``x − L[:, i]``; weights ``W_m0 = λ / (n + λ)``,
``W_c0 = W_m0 + 1 − α² + β``, ``W_i = 1 / (2 (n + λ))`` (α, β, κ in
:class:`~uuv_ocp.estimation.base.EstimatorOptions`).  The 2n + 1 points are propagated by the
model mapped over them (one compiled call).  The update draws fresh sigma points of the
predicted ``(x⁻, P⁻)``, so that they carry the process noise ``Q`` (as filterpy's
``UnscentedKalmanFilter`` 2.0 does: the two agree to rounding), maps the sensors over them
(one call) and forms ``S = Σ W_c (Z − ẑ)(Z − ẑ)ᵀ + R``, ``P_xz = Σ W_c (X − x⁻)(Z − ẑ)ᵀ``,
``K = P_xz S⁻¹``, ``x = x⁻ + K y``, ``P = P⁻ − K S Kᵀ``; only the rows of the sensors that
reported enter.  Angular outputs are averaged about the centre point's value and their
residuals wrapped.
"""

from __future__ import annotations

import casadi as ca
import numpy as np

from uuv_ocp.estimation.base import Estimator, buffered, register_estimator, wrap


class UnscentedKalmanFilter(Estimator):
    """UKF (module doc); build with ``uo.Estimator(problem, "ukf", sensors=...)``."""

    name = "ukf"

    def _build(self) -> None:
        m, o = self.model, self.options
        n = m.size
        points = 2 * n + 1
        lam = o.alpha**2 * (n + o.kappa) - n
        self.scale = n + lam
        self.Wm = np.full(points, 1.0 / (2.0 * self.scale))
        self.Wc = self.Wm.copy()
        self.Wm[0] = lam / self.scale
        self.Wc[0] = lam / self.scale + 1.0 - o.alpha**2 + o.beta
        f = ca.Function("ukf_f", m.inputs, [m.f])
        h = ca.Function("ukf_h", [m.xa], [m.h])
        X = ca.SX.sym("X", n, points)
        mapped = f.map(points)(X, m.u, m.ps, m.pg)
        self._propagate = buffered("ukf_propagate", [X, m.u, m.ps, m.pg], [mapped])
        self._measure = buffered("ukf_measure", [X], [h.map(points)(X)])

    def sigma_points(self, x: np.ndarray, P: np.ndarray) -> np.ndarray:
        """Return the 2n + 1 sigma points of ``(x, P)`` as columns (module doc)."""
        L = _square_root(self.scale * P)
        return np.hstack([x[:, None], x[:, None] + L, x[:, None] - L])

    def predict(self, u: object) -> None:
        """Propagate the sigma points: ``x⁻ = Σ W_m X``, ``P⁻ = Σ W_c (X − x⁻)(X − x⁻)ᵀ + Q``."""
        m = self.model
        n = m.size
        points = 2 * n + 1
        X = self.sigma_points(self.x, self.P)
        (Xf,) = self._propagate(X, self._control(u), m.p_stage, m.p_global)
        Xf = Xf.reshape(n, points, order="F")
        self.x = Xf @ self.Wm
        dX = Xf - self.x[:, None]
        P = (dX * self.Wc) @ dX.T + m.Q
        self.P = 0.5 * (P + P.T)
        self.steps += 1

    def _update(self, rows: np.ndarray, z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        n = self.model.size
        X = self.sigma_points(self.x, self.P)
        Z = self._measure(X)[0].reshape(-1, 2 * n + 1, order="F")[rows]
        angular = self.angular[rows]
        dZ = Z - Z[:, :1]
        if angular.any():
            dZ[angular] = wrap(dZ[angular])
        predicted = Z[:, 0] + dZ @ self.Wm
        dZ = dZ - (dZ @ self.Wm)[:, None]
        S = (dZ * self.Wc) @ dZ.T
        S[np.diag_indices_from(S)] += self.R[rows]
        dX = X - self.x[:, None]
        Pxz = (dX * self.Wc) @ dZ.T
        K = np.linalg.solve(S, Pxz.T).T
        y = self._residual(rows, z, predicted)
        self.x = self.x + K @ y
        P = self.P - K @ S @ K.T
        self.P = 0.5 * (P + P.T)
        return y, S


register_estimator("ukf", UnscentedKalmanFilter)


def _square_root(matrix: np.ndarray) -> np.ndarray:
    """Return ``L`` with ``L Lᵀ = matrix``: Cholesky, or the eigen-square-root of its PSD part.

    ``P − K S Kᵀ`` can lose definiteness to rounding when a sensor is far more precise than
    the prior; its negative eigenvalues (rounding) are then clipped to zero instead of stopping
    the filter (the EKF's Joseph form keeps definiteness by construction).
    """
    try:
        root: np.ndarray = np.linalg.cholesky(matrix)
        return root
    except np.linalg.LinAlgError:
        values, vectors = np.linalg.eigh(0.5 * (matrix + matrix.T))
        clipped: np.ndarray = vectors * np.sqrt(np.clip(values, 0.0, None))
        return clipped
