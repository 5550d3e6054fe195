"""Moving-horizon estimator on the augmented model (:mod:`uuv_ocp.estimation.base`).

The window holds the last ``M`` control intervals (``options.horizon``), nodes
``s = k − M, …, k`` (fewer before ``M`` steps have passed: the window grows from the prior of
:meth:`reset`).  Its decision variables are the augmented states of all nodes (multiple
shooting); the process noise is additive, ``w_i = x_{i+1} − f(x_i, u_i)``, so it is eliminated
and the problem is an unconstrained nonlinear least-squares problem:

    min  ‖x_s − x̄_s‖²_{P̄_s⁻¹} + Σ_i ‖x_{i+1} − f(x_i, u_i)‖²_{Q⁻¹} + Σ_i ‖y_i − h(x_i)‖²_{R_i⁻¹}

where ``y_i`` holds only the outputs of the sensors that reported at step ``i`` (a 0/1 mask on
the weights ``R⁻¹``, so one compiled Function serves every multi-rate window) and angular
residuals are wrapped into (−π, π].  Multiple shooting rather than single shooting
(``x_s, w_s, …``): its Gauss–Newton Hessian is block tridiagonal, solved by a block Cholesky
in O(M n³) (single shooting's is dense, O(M³ n³)), and it is less nonlinear over long windows.

**Gauss–Newton step.**  With ``H_i = ∂h/∂x (x_i)`` and ``F_i = ∂f/∂x (x_i, u_i)`` (CasADi's AD),
the normal equations ``A δ = b`` are block tridiagonal; the forward elimination
``D_i = A_ii − C_i D_{i−1}⁻¹ C_iᵀ`` (``C_i = −Q⁻¹ F_{i−1}``) is a Kalman filter in information
form, the back substitution the Rauch–Tung–Striebel smoother.  The whole step (residuals,
Jacobians, normal equations, factorisation, solve) is one CasADi SX Function of fixed size, called
through :class:`~uuv_ocp.native.buffered.BufferedFunction`; the growing window uses the same
Function with the unused leading nodes decoupled (zero weights, an identity block).  The
covariance reported is ``D_k⁻¹``, the inverse of the last Schur complement: the Gauss–Newton
approximation of the newest state's marginal covariance (on a linear-Gaussian model exactly the
Kalman filter's ``P_{k|k}``).

**Modes.**  ``mode="full"``: Gauss–Newton iterations with an Armijo backtracking line search on
the cost until the decrement ``bᵀδ`` falls below ``options.tolerance`` (relative to the cost)
or ``options.max_iterations``: the exact minimiser (the gradient is exact; only the Hessian is
approximated, which does not move the stationary point).  ``mode="rti"``: one full Gauss–Newton
step per control step from the shifted previous solution (the new node predicted by ``f``), as
real-time iterations do (Diehl et al. 2005; Kühl et al. 2011 for MHE).  On a linear-Gaussian
model one step is exact, so both modes agree.

**Arrival cost (the filtering update, Rao, Rawlings and Mayne 2003, IEEE TAC 48(2); Rao,
Rawlings and Lee 2001, Automatica 37(10)).**  When the window slides from start ``s`` to
``s + 1``, the prior ``(x̄_s, P̄_s)`` is corrected with the measurement of step ``s`` and
predicted over interval ``s`` by an EKF linearised at the MHE's own smoothed estimate
``x̂_s`` of that node (Kühl et al. 2011, Computers & Chemical Engineering 35(1); Baumgartner
et al. 2020, eqs. 18):

    ỹ   = wrap(y_s − h(x̂_s)) − H (x̄_s − x̂_s)            H = ∂h/∂x (x̂_s), reported rows only
    S   = H P̄_s Hᵀ + R,   K = P̄_s Hᵀ S⁻¹
    x⁺  = x̄_s + K ỹ,      P⁺ = (I − K H) P̄_s (I − K H)ᵀ + K R Kᵀ      (Joseph form)
    x̄_{s+1} = f(x̂_s, u_s) + F (x⁺ − x̂_s),   P̄_{s+1} = F P⁺ Fᵀ + Q     F = ∂f/∂x (x̂_s, u_s)

``R`` and ``Q`` are covariances here (the cost's weights are their inverses), the noise enters
additively (its Jacobian is the identity) and the prediction takes the noise at its prior mean,
zero: not the smoothed ``ŵ_s``, which would count the window's information twice.  CasADi's
official example ``mhe_spring_damper.py`` (casadi#4226) uses the weight ``R⁻¹`` where the gain
needs the covariance ``R``, adds ``Q⁻¹`` unmapped by the noise Jacobian, and propagates with the
smoothed noise; on a linear-Gaussian model the update above is the Kalman filter's, and the MHE
equals the Kalman filter at the newest node and the Rauch–Tung–Striebel smoother over the window
(``tests/estimation/test_mhe.py``).

**Undefined measurements.**  A sensor that did not report never enters (its rows are masked with
``if_else``, so a NaN or Inf of its ``h`` or Jacobian at the linearisation point is not multiplied
by the zero weight).  A sensor that reported but is undefined where the window is linearised
(a range at its beacon) gives no Gauss–Newton direction: the solve does not move (the estimate
stays the last iterate with the covariance of the last finite linearisation, the prediction's if
there is none), and when that node leaves the window the undefined rows are dropped from the
arrival cost.  The full solve also stays put when no step along the Gauss–Newton direction decreases the
cost (Armijo fails down to a step of 1e-8).

**Innovations.**  As the EKF's: the newest step's reporting rows against the prediction
``f(x̂_{k−1}, u_{k−1})``, with ``S = H P⁻ Hᵀ + R`` and ``P⁻ = F P_{k−1} Fᵀ + Q`` from the
previous step's covariance.
"""

from __future__ import annotations

import casadi as ca
import numpy as np

from uuv_ocp._concurrency import BUILD_LOCK
from uuv_ocp.estimation.base import Estimate, Estimator, register_estimator
from uuv_ocp.estimation.sensors import Measurement
from uuv_ocp.native.buffered import BufferedFunction
from uuv_ocp.native.compile import default_cache_directory, load_or_fallback


def _function(name: str, inputs: list[ca.SX], outputs: list[ca.SX]) -> ca.Function:
    """Return a Function of dense outputs (a sparse one would make BufferedFunction wrap it in MX)."""
    with BUILD_LOCK:
        return ca.Function(name, inputs, [ca.densify(output) for output in outputs])


def _cholesky(A: ca.SX) -> list[list[ca.SX]]:
    """Lower Cholesky factor of a symmetric positive definite SX matrix, as nested lists."""
    n = A.shape[0]
    L = [[ca.SX(0)] * n for _ in range(n)]
    for j in range(n):
        diagonal = A[j, j] - sum((L[j][k] * L[j][k] for k in range(j)), ca.SX(0))
        L[j][j] = ca.sqrt(diagonal)
        for i in range(j + 1, n):
            entry = A[i, j] - sum((L[i][k] * L[j][k] for k in range(j)), ca.SX(0))
            L[i][j] = entry / L[j][j]
    return L


def _forward(L: list[list[ca.SX]], B: ca.SX) -> ca.SX:
    """``L⁻¹ B`` by forward substitution (``L`` lower triangular)."""
    n = len(L)
    rows: list[ca.SX] = []
    for i in range(n):
        row = B[i, :]
        for k in range(i):
            row = row - L[i][k] * rows[k]
        rows.append(row / L[i][i])
    return ca.vertcat(*rows)


def _backward(L: list[list[ca.SX]], B: ca.SX) -> ca.SX:
    """``L⁻ᵀ B`` by back substitution."""
    n = len(L)
    rows: list[ca.SX] = [ca.SX(0)] * n
    for i in reversed(range(n)):
        row = B[i, :]
        for k in range(i + 1, n):
            row = row - L[k][i] * rows[k]
        rows[i] = row / L[i][i]
    return ca.vertcat(*rows)


def _gram(V: ca.SX) -> ca.SX:
    """``Vᵀ V``, each entry of the symmetric result computed once."""
    n = V.shape[1]
    G = ca.SX(n, n)
    for j in range(n):
        for i in range(j, n):
            G[i, j] = ca.dot(V[:, i], V[:, j])
            if i != j:
                G[j, i] = G[i, j]
    return G


def _wrapped(residual: ca.SX, angular: np.ndarray) -> ca.SX:
    """Return the residual with its angular entries wrapped into (−π, π] (derivative 1)."""
    entries = [
        ca.atan2(ca.sin(residual[i]), ca.cos(residual[i])) if angular[i] else residual[i]
        for i in range(residual.shape[0])
    ]
    return ca.vertcat(*entries) if entries else residual


def _masked(mask: ca.SX, value: ca.SX) -> ca.SX:
    """Return ``value`` with the rows whose ``mask`` entry is 0 set to 0, even if NaN or Inf there.

    ``mask * value`` would not do: 0 · NaN = NaN, and a sensor that did not report may have an
    undefined output or Jacobian at the linearisation point (a range or bearing at its beacon).
    """
    rows = [ca.if_else(mask[r], value[r, :], ca.SX.zeros(1, value.shape[1])) for r in range(value.shape[0])]
    return ca.vertcat(*rows) if rows else value


def _information(P: np.ndarray) -> np.ndarray:
    """Return ``P⁻¹``; ``ValueError`` if ``P`` is not positive definite."""
    try:  # the arrival cost weighs with P⁻¹: a merely semi-definite prior has none
        factor = np.linalg.cholesky(P)
    except np.linalg.LinAlgError:
        raise ValueError(
            "covariance must be positive definite for the MHE (its arrival cost is P⁻¹)"
        ) from None
    inverse = np.linalg.inv(factor)
    return inverse.T @ inverse


class MovingHorizonEstimator(Estimator):
    """MHE (module doc); build with ``uo.Estimator(problem, "mhe", sensors=...)``.

    ``options.horizon`` (window of ``M`` control steps, default 20), ``options.mode``
    (``"full"`` or ``"rti"``), ``options.max_iterations`` and ``options.tolerance`` tune it
    (:class:`~uuv_ocp.estimation.base.EstimatorOptions`).
    """

    name = "mhe"

    def _build(self) -> None:
        m, o = self.model, self.options
        n, M = m.size, o.horizon
        nodes = M + 1
        rows = int(self.R.size)
        self.horizon = M
        f = ca.Function("mhe_f", m.inputs, [m.f, ca.jacobian(m.f, m.xa)])
        h = ca.Function("mhe_h", [m.xa], [m.h, ca.jacobian(m.h, m.xa)])
        Q = ca.DM(m.Q)
        q = ca.DM(1.0 / np.diag(m.Q))  # Q is diagonal (AugmentedModel)

        # the EKF's prediction: the new node's warm start and the innovations' S
        P = ca.SX.sym("P", n, n)
        fx, Fx = f(*m.inputs)
        hp, Hp = h(fx)
        covariance = Fx @ P @ Fx.T + Q
        functions = [
            _function("mhe_predict", [*m.inputs, P], [fx, 0.5 * (covariance + covariance.T), hp, Hp]),
            _function("mhe_measure", [m.xa], list(h(m.xa))),
        ]

        # the arrival cost's filtering update (module doc), linearised at the smoothed node
        xbar, xs = ca.SX.sym("xbar", n), ca.SX.sym("xs", n)
        z, mask = ca.SX.sym("z", rows), ca.SX.sym("mask", rows)
        h0, H0 = h(xs)
        H0 = _masked(mask, H0)  # rows that did not report: zero (no information)
        R = ca.diag(ca.DM(self.R))
        innovation = _masked(mask, _wrapped(z - h0, self.angular) - H0 @ (xbar - xs))
        PHt = P @ H0.T
        K = ca.solve(H0 @ PHt + R, PHt.T).T
        A = ca.DM.eye(n) - K @ H0
        filtered_P = A @ P @ A.T + K @ R @ K.T
        f0, F0 = f(xs, m.u, m.ps, m.pg)
        prior = f0 + F0 @ (xbar + K @ innovation - xs)
        prior_P = F0 @ filtered_P @ F0.T + Q
        prior_P = 0.5 * (prior_P + prior_P.T)
        factor = _cholesky(prior_P)
        prior_Pinv = _backward(factor, _forward(factor, ca.SX.eye(n)))
        functions.append(
            _function(
                "mhe_arrival",
                [xbar, P, xs, m.u, m.ps, m.pg, z, mask],
                [prior, prior_P, 0.5 * (prior_Pinv + prior_Pinv.T)],
            )
        )

        # one Gauss–Newton step of the whole window (module doc)
        X = ca.SX.sym("X", n, nodes)
        U = ca.SX.sym("U", m.nu, M)
        Z = ca.SX.sym("Z", rows, nodes)
        W = ca.SX.sym("W", rows, nodes)  # the 0/1 mask of reported rows
        active = ca.SX.sym("active", M)  # intervals in the window
        prior_weight = ca.SX.sym("prior_weight", nodes)  # 1 at the window's first node
        ghost = ca.SX.sym("ghost", nodes)  # 1 at nodes before it (decoupled: identity block)
        xbar_in, Pinv = ca.SX.sym("xbar", n), ca.SX.sym("Pinv", n, n)
        Rinv = ca.DM(1.0 / self.R)
        diag_blocks: list[ca.SX] = []
        rhs: list[ca.SX] = []
        cost = ca.SX(0)
        for i in range(nodes):
            hi, Hi = h(X[:, i])
            Hi = _masked(W[:, i], Hi)
            weight = W[:, i] * Rinv
            residual = _masked(W[:, i], _wrapped(Z[:, i] - hi, self.angular))
            deviation = xbar_in - X[:, i]
            diag_blocks.append(Hi.T @ ca.diag(weight) @ Hi + prior_weight[i] * Pinv + ghost[i] * ca.SX.eye(n))
            rhs.append(Hi.T @ (weight * residual) + prior_weight[i] * (Pinv @ deviation))
            cost += 0.5 * ca.dot(weight * residual, residual)
            cost += 0.5 * prior_weight[i] * ca.dot(deviation, Pinv @ deviation)
        couplings: list[ca.SX] = []  # C_{i+1} = A_{i+1,i}
        for i in range(M):
            fi, Fi = f(X[:, i], U[:, i], m.ps, m.pg)
            qi = active[i] * q
            residual = X[:, i + 1] - fi
            QF = ca.diag(qi) @ Fi
            diag_blocks[i] += _gram(ca.diag(ca.sqrt(qi)) @ Fi)
            diag_blocks[i + 1] += ca.diag(qi)
            couplings.append(-QF)
            rhs[i] += QF.T @ residual
            rhs[i + 1] -= qi * residual
            cost += 0.5 * ca.dot(qi * residual, residual)
        # forward block elimination (an information filter), then back substitution (a smoother)
        factors = [_cholesky(diag_blocks[0])]
        reduced = [rhs[0]]
        for i in range(1, nodes):
            C = couplings[i - 1]
            # C D⁻¹ Cᵀ = Vᵀ V with V = L⁻¹ Cᵀ
            V = _forward(factors[-1], C.T)
            reduced.append(rhs[i] - V.T @ _forward(factors[-1], reduced[-1]))
            factors.append(_cholesky(diag_blocks[i] - _gram(V)))
        steps: list[ca.SX] = [ca.SX(0)] * nodes
        steps[-1] = _backward(factors[-1], _forward(factors[-1], reduced[-1]))
        for i in reversed(range(nodes - 1)):
            right = reduced[i] - couplings[i].T @ steps[i + 1]
            steps[i] = _backward(factors[i], _forward(factors[i], right))
        step = ca.horzcat(*steps)
        newest = _backward(factors[-1], _forward(factors[-1], ca.SX.eye(n)))
        decrement = sum((ca.dot(rhs[i], steps[i]) for i in range(nodes)), ca.SX(0))
        inputs = [X, U, Z, W, active, prior_weight, ghost, xbar_in, Pinv, m.ps, m.pg]
        functions.append(
            _function("mhe_gauss_newton", inputs, [step, 0.5 * (newest + newest.T), cost, decrement])
        )
        functions.append(_function("mhe_cost", inputs, [cost]))
        by_name = {function.name(): function for function in functions}
        self.compiled = False
        if o.compiled:
            # -O1: no flag was faster on the straight-line Gauss–Newton step in three runs, and
            # -O1 builds in about half the time of -O2/-O3 (docs/benchmarks.md); verified
            # against the VM, cached by content
            loaded, library = load_or_fallback(
                functions,
                default_cache_directory(),
                name="uuv_ocp_mhe",
                flags=("-O1", "-fPIC", "-shared"),
                tolerance=1e-9,
            )
            by_name, self.compiled = loaded, library is not None
        self._predict, self._measure, self._arrival, self._gauss_newton, self._cost = (
            BufferedFunction(by_name[name])
            for name in ("mhe_predict", "mhe_measure", "mhe_arrival", "mhe_gauss_newton", "mhe_cost")
        )
        self._nodes = nodes
        self._window_reset()

    # ------------------------------------------------------------- the window
    def _window_reset(self) -> None:
        """Empty the window: node ``M`` only, holding the prior (``self.x``, ``self.P``)."""
        m, M = self.model, self.horizon
        nodes, rows = M + 1, self.R.size
        self._X = np.tile(self.x[:, None], (1, nodes))
        self._U = np.zeros((m.nu, M))
        self._Z = np.zeros((rows, nodes))
        self._W = np.zeros((rows, nodes))
        self._length = 0  # intervals in the window
        self._prior = self.x.copy()
        self._prior_P = self.P.copy()
        self._prior_Pinv = _information(self.P)
        self._sensors: tuple[int, ...] = ()
        self._h: np.ndarray | None = None
        self._H: np.ndarray | None = None
        self.iterations = 0

    def _check_prior(self, P: np.ndarray) -> None:
        _information(P)

    def _reset_hook(self) -> None:
        self._window_reset()

    def _masks(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        M, L = self.horizon, self._length
        start = M - L
        active = np.zeros(M)
        active[start:] = 1.0
        prior_weight = np.zeros(M + 1)
        prior_weight[start] = 1.0
        ghost = np.zeros(M + 1)
        ghost[:start] = 1.0
        return active, prior_weight, ghost

    @property
    def window(self) -> tuple[np.ndarray, np.ndarray]:
        """The window's steps and its estimates of their augmented states (columns), oldest first."""
        L = self._length
        first = self.steps - L
        return np.arange(first, self.steps + 1), self._X[:, self.horizon - L :].copy()

    def predict(self, u: object) -> None:
        """Slide the window by one interval under ``u`` (the arrival cost updated if it was full).

        The new node is predicted by the model from the newest estimate; the estimate is the
        EKF's prediction ``x⁻ = f(x)``, ``P⁻ = F P Fᵀ + Q`` until :meth:`correct`.
        """
        m, M = self.model, self.horizon
        u = self._control(u)
        if self._length == M:
            # the oldest node leaves: its information goes into the prior (module doc)
            leaving = (self._prior, self._prior_P, self._X[:, 0], self._U[:, 0], m.p_stage, m.p_global)
            prior, prior_P, prior_Pinv = self._arrival(*leaving, self._Z[:, 0], self._W[:, 0])
            if not (np.isfinite(prior).all() and np.isfinite(prior_Pinv).all()):
                # a reporting sensor undefined at the leaving node (the solve could not move it
                # off a range's beacon): those rows are dropped, the others kept
                h, H = self._measure(self._X[:, 0])
                H = H.reshape(h.size, m.size, order="F")
                defined = np.isfinite(h) & np.isfinite(H).all(axis=1)
                prior, prior_P, prior_Pinv = self._arrival(*leaving, self._Z[:, 0], self._W[:, 0] * defined)
            n = m.size
            self._prior = prior
            self._prior_P = prior_P.reshape(n, n, order="F")
            self._prior_Pinv = prior_Pinv.reshape(n, n, order="F")
        else:
            self._length += 1
        x, P, h, H = self._predict(self.x, u, m.p_stage, m.p_global, self.P)
        for array in (self._X, self._Z, self._W):
            array[:, :-1] = array[:, 1:]
        self._U[:, :-1] = self._U[:, 1:]
        self._U[:, -1] = u
        self._X[:, -1] = x
        self._Z[:, -1] = 0.0
        self._W[:, -1] = 0.0
        n = m.size
        self.x = x
        self.P = P.reshape(n, n, order="F")
        self._h, self._H = h, H.reshape(h.size, n, order="F")
        self.steps += 1

    def correct(self, measurement: Measurement) -> Estimate:
        """Put the newest step's measurements in the window and solve it (module doc)."""
        rows = self.measured_rows(measurement)
        m = self.model
        innovations, S = np.zeros(0), np.zeros((0, 0))
        if rows.size:
            h, H = self._h, self._H
            if h is None or H is None:  # no prediction since the last solve: at the estimate
                h, H = self._measure(self.x)
                H = H.reshape(h.size, m.size, order="F")
            H = H[rows]
            innovations = self._residual(rows, measurement.values, h[rows])
            S = H @ self.P @ H.T + np.diag(self.R[rows])
            self._Z[rows, -1] = measurement.values
            self._W[rows, -1] = 1.0
        self._solve()
        self._h = self._H = None
        return self.estimate(measurement.step, measurement.sensors, innovations, S)

    def _solve(self) -> None:
        """Gauss–Newton on the window: one step (``"rti"``) or to convergence (``"full"``)."""
        m, o = self.model, self.options
        n = m.size
        active, prior_weight, ghost = self._masks()
        fixed = (self._U, self._Z, self._W, active, prior_weight, ghost, self._prior, self._prior_Pinv)
        fixed_tail = (m.p_stage, m.p_global)
        iterations = 1 if o.mode == "rti" else o.max_iterations
        X = self._X
        # no finite linearisation at all: the estimate stays the prediction (x⁻, P⁻ of predict)
        covariance = None
        done, stale = 0, False
        for _ in range(iterations):
            step, linearised, cost, decrement = self._gauss_newton(X, *fixed, *fixed_tail)
            done, stale = done + 1, False
            if not (
                np.isfinite(step).all()
                and np.isfinite(linearised).all()
                and np.isfinite(cost).all()
                and np.isfinite(decrement).all()
            ):
                # a reporting sensor undefined at X (a range at its beacon): no direction to
                # move in; X stays, with the covariance of the last finite linearisation
                break
            covariance = linearised
            step = step.reshape(n, self._nodes, order="F")
            if o.mode == "rti":
                # the covariance of the linearisation the step used (as the RTI's own)
                X = X + step
                break
            # Armijo backtracking on the cost: bᵀδ is minus the directional derivative
            slope = float(decrement[0])
            if slope <= o.tolerance * max(1.0, float(cost[0])):
                break
            alpha, accepted = 1.0, False
            while alpha >= 1e-8:
                trial = X + alpha * step
                (trial_cost,) = self._cost(trial, *fixed, *fixed_tail)
                # a NaN trial cost fails the test: a shorter step
                if trial_cost[0] <= cost[0] - 1e-4 * alpha * slope:
                    accepted = True
                    break
                alpha *= 0.5
            if not accepted:
                # no step decreases the cost (rounding at the minimiser, or a cost undefined
                # along the step): X stays, and its covariance is this linearisation's
                break
            X, stale = trial, True
        if stale and o.mode == "full":
            # out of iterations after a move: the covariance at the last iterate, if finite
            _, linearised, _, _ = self._gauss_newton(X, *fixed, *fixed_tail)
            if np.isfinite(linearised).all():
                covariance = linearised
        if covariance is None:
            covariance = self.P
        self._X = X
        self.iterations = done
        self.x = X[:, -1].copy()
        self.P = covariance.reshape(n, n, order="F")


register_estimator("mhe", MovingHorizonEstimator)
