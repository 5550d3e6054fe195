"""Result and warm-start types shared by every solver backend."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass(frozen=True)
class Iterate:
    """Warm-start information carried from one solve to the next.

    Parameters
    ----------
    scaled_controls : numpy.ndarray, shape (N, 3)
        Scaled controls ``τ / τ_max`` of the plan.
    states : numpy.ndarray, shape (N+1, 6)
        Predicted states of the plan.
    primal : numpy.ndarray or None
        Full NLP primal vector (exact solvers), in the layout of ``variant``.
    lam_g, lam_x : numpy.ndarray or None
        Constraint and bound multipliers (exact solvers).
    variant : {"hard", "soft"}
        Which NLP layout ``primal`` and the multipliers belong to.
    terminal_relaxed : bool
        Whether the plan needed the exact-penalty terminal fallback.
    primal_shift, constraint_shift : numpy.ndarray or None
        Index maps that move every NLP stage k+1 to stage k (last stage repeated), used by
        :meth:`shift` on ``primal``/``lam_x`` and ``lam_g``.
    """

    scaled_controls: np.ndarray
    states: np.ndarray
    primal: np.ndarray | None = None
    lam_g: np.ndarray | None = None
    lam_x: np.ndarray | None = None
    variant: str = "hard"
    terminal_relaxed: bool = False
    primal_shift: np.ndarray | None = None
    constraint_shift: np.ndarray | None = None

    def shift(self) -> Iterate:
        """Drop the first interval and repeat the last: the receding-horizon warm start.

        Plans and (when the index maps are known) NLP primal and dual vectors
        are all shifted by one stage.
        """
        controls = np.concatenate((self.scaled_controls[1:], self.scaled_controls[-1:]))
        states = np.concatenate((self.states[1:], self.states[-1:]))
        return Iterate(
            scaled_controls=controls,
            states=states,
            variant=self.variant,
            terminal_relaxed=self.terminal_relaxed,
            primal=_take(self.primal, self.primal_shift),
            lam_g=_take(self.lam_g, self.constraint_shift),
            lam_x=_take(self.lam_x, self.primal_shift),
            primal_shift=self.primal_shift,
            constraint_shift=self.constraint_shift,
        )


def _take(values: np.ndarray | None, index: np.ndarray | None) -> np.ndarray | None:
    if values is None or index is None:
        return None
    return values[index]


@dataclass(frozen=True)
class SolveResult:
    """Outcome of one solve of a problem instance (an Ocp or a tracking preset).

    Parameters
    ----------
    solver : str
        Registered name of the backend.
    controls : numpy.ndarray, shape (N, 3)
        Planned controls (N, N, N·m).
    states : numpy.ndarray, shape (N+1, 6)
        States predicted by the controller's model under ``controls`` (exact solvers: the
        NLP's states on success, where they satisfy the dynamics to the solver's tolerance;
        the model's rollout of ``controls`` on a failure, whose NLP states need not).
    cost : float
        Objective from :func:`uuv_ocp.score` (the common judge).
    max_violation : float
        Largest constraint violation from :func:`uuv_ocp.score`.
    success : bool
        Whether the backend reports convergence (for swarms: the budget was used and the
        result is finite).
    status : str
        Backend status text; ``"soft_terminal: ..."`` when the exact-penalty fallback was used.
    solve_time : float
        Wall-clock time of the whole solve, fallback included (s).
    iterations : int
        Iterations of the backend (summed over fallback attempts).
    evaluations : int
        Objective evaluations (NLP ``f`` calls, or swarm candidates evaluated).
    terminal_relaxed : bool
        ``True`` when the hard terminal equality was infeasible and the soft version was solved.
    iterate : Iterate
        Warm start for the next solve.
    history : numpy.ndarray or None
        Best cost after each iteration (swarm solvers).
    """

    solver: str
    controls: np.ndarray
    states: np.ndarray
    cost: float
    max_violation: float
    success: bool
    status: str
    solve_time: float
    iterations: int
    evaluations: int
    terminal_relaxed: bool
    iterate: Iterate
    history: np.ndarray | None = None
    details: dict = field(default_factory=dict, compare=False)
