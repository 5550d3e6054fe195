"""Result and warm-start types shared by every solver backend."""

from __future__ import annotations

import dataclasses
import enum
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field
from typing import Any, NamedTuple

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

    def is_finite(self) -> bool:
        """Whether every number of the plan, the primal and the multipliers is finite.

        A warm start that is not (a diverged iteration, a QP that overflowed) would make the
        next solve start from NaN: :class:`~uuv_ocp.NMPC` never keeps one.
        """
        arrays = (self.scaled_controls, self.states, self.primal, self.lam_g, self.lam_x)
        return all(array is None or bool(np.isfinite(array).all()) for array in arrays)


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
    details : SolveDetails
        What the backend reports beyond these fields (a mapping too: ``details["attempts"]``);
        a plain mapping given here is converted by :meth:`SolveDetails.of`.
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
    details: SolveDetails = field(default_factory=lambda: SolveDetails(), compare=False)

    def __post_init__(self) -> None:
        """Turn a plug-in's plain ``details`` mapping into :class:`SolveDetails`."""
        if not isinstance(self.details, SolveDetails):
            object.__setattr__(self, "details", SolveDetails.of(self.details))


class Variant(str):
    """Name of an NLP layout of a problem: ``"hard"``, ``"soft"`` or ``"soft_x<factor>"``.

    A ``str`` (so it is the key of ``NlpSolver.variants``, of warm starts and of the C steps'
    caches, and compares equal to its spelling) that knows what it stands for: :attr:`soft`
    and :attr:`penalty_factor` replace parsing the spelling at every use.
    """

    __slots__ = ()

    def __new__(cls, name: str) -> Variant:
        """Check the spelling (``ValueError`` naming the accepted forms otherwise)."""
        if name not in ("hard", "soft") and not (
            isinstance(name, str) and name.startswith("soft_x") and _is_factor(name[len("soft_x") :])
        ):
            raise ValueError(f"variant must be 'hard', 'soft' or 'soft_x<factor>', got {name!r}")
        return super().__new__(cls, name)

    @classmethod
    def escalated(cls, factor: float) -> Variant:
        """Return the soft layout with its exact-penalty weight multiplied by ``factor`` (> 0)."""
        return cls(f"soft_x{factor:g}")

    @property
    def soft(self) -> bool:
        """Whether this layout has the terminal slacks of the exact-penalty NLP."""
        return self != "hard"

    @property
    def penalty_factor(self) -> float | None:
        """Factor on the soft NLP's penalty weight (``None`` for the hard NLP, 1 for ``"soft"``)."""
        if self == "hard":
            return None
        return 1.0 if self == "soft" else float(self[len("soft_x") :])


def _is_factor(text: str) -> bool:
    try:
        return float(text) > 0.0
    except ValueError:
        return False


HARD = Variant("hard")
SOFT = Variant("soft")


class Stage(enum.Enum):
    """Which settings an attempt of an exact backend's fallback chain ran with."""

    PLAIN = "plain"
    """The backend's own plugin and settings."""
    ROBUST = "robust"
    """The last-resort retry (``NlpSolver.robust_options``)."""
    RESCUE = "rescue"
    """Another plugin from the last iterate (``NlpSolver.rescue_options``)."""

    @property
    def suffix(self) -> str:
        """Return ``""``, ``" (robust)"`` or ``" (rescue)"``: how attempt labels name the stage."""
        return "" if self is Stage.PLAIN else f" ({self.value})"


class AttemptSummary(NamedTuple):
    """One attempt as a result lists it: ``(label, status, iterations)``."""

    label: str
    """The variant and the stage, e.g. ``"soft_x100 (robust)"``."""
    status: str
    iterations: int


@dataclass(frozen=True, eq=False)
class Attempt:
    """One try of an exact backend's fallback chain: what it started from and what it reached.

    What :meth:`~uuv_ocp.solvers.nlp.NlpSolver._attempt` returns (an exact backend that is not a
    CasADi ``nlpsol`` overrides it; see docs/solvers.md).  Multipliers are those of the
    unscaled objective.

    Parameters
    ----------
    variant : Variant
        The NLP layout solved.
    stage : Stage
        The settings it ran with.
    still_water : bool
        Whether the still-water specialisation of the NLP was solved.
    primal, lam_g, lam_x : numpy.ndarray
        The iterate reached (primal vector, constraint and bound multipliers) in ``variant``'s layout.
    success : bool
        Whether the attempt converged to a plan the backend vouches for.
    status : str
        The solver's status text.
    iterations, evaluations : int
        Iterations and objective evaluations of the attempt.
    solver_time : float
        Wall time inside the solver (s).
    watched : bool
        Whether it ran in the watchdog's worker process.
    qp_iterations : int or None
        QP iterations of a real-time iteration's C step (``None``: not reported).
    """

    variant: Variant
    stage: Stage
    still_water: bool
    primal: np.ndarray
    lam_g: np.ndarray
    lam_x: np.ndarray
    success: bool
    status: str
    iterations: int
    evaluations: int
    solver_time: float
    watched: bool = False
    qp_iterations: int | None = None

    @property
    def label(self) -> str:
        """The variant and the stage, e.g. ``"hard (rescue)"``."""
        return self.variant + self.stage.suffix

    def summary(self) -> AttemptSummary:
        """Return ``(label, status, iterations)``, what :class:`SolveDetails` keeps."""
        return AttemptSummary(self.label, self.status, self.iterations)


_DETAIL_FIELDS = (
    "attempts",
    "deadline_hit",
    "attempts_skipped",
    "build_time",
    "plugin_time",
    "still_water",
    "c_time",
)


@dataclass(frozen=True, eq=False)
class SolveDetails(Mapping[str, Any]):
    """What a :class:`SolveResult` reports beyond its common fields; also read as a mapping.

    ``result.details.deadline_hit`` and ``result.details["deadline_hit"]`` are the same value;
    a field that is ``None`` was not reported by the backend and is absent from the mapping.
    Backend-specific entries (a swarm's ``"fitness"`` and ``"candidates"``, a hybrid's
    ``"swarm_fitness"``, a multi-start's ``"starts"``, ...) are in :attr:`extra` and read the
    same way.

    Parameters
    ----------
    attempts : tuple of AttemptSummary or None
        Every attempt of an exact backend's fallback chain, in order.
    deadline_hit : bool or None
        Whether the plan was late (``deadline`` option or ``time_limit``).
    attempts_skipped : int or None
        Attempts the deadline kept from starting.
    build_time : float or None
        Time spent building solver plugins during the call, outside the deadline (s).
    plugin_time : float or None
        Time inside the solver plugins (s).
    still_water : bool or None
        Whether the still-water specialisation of the NLP was solved.
    c_time : float or None
        Time the real-time iteration's C step measured itself (s).
    extra : Mapping
        Backend-specific entries by name.
    """

    attempts: tuple[AttemptSummary, ...] | None = None
    deadline_hit: bool | None = None
    attempts_skipped: int | None = None
    build_time: float | None = None
    plugin_time: float | None = None
    still_water: bool | None = None
    c_time: float | None = None
    extra: Mapping[str, Any] = field(default_factory=dict)

    @classmethod
    def of(cls, entries: Mapping[str, Any] | None) -> SolveDetails:
        """Return the details of a mapping (a plug-in's ``details={...}``): known keys to fields."""
        if isinstance(entries, SolveDetails):
            return entries
        if entries is None:
            return cls()
        if not isinstance(entries, Mapping):
            raise ValueError(f"details must be a mapping of names to values, got {type(entries).__name__}")
        known = {key: entries[key] for key in _DETAIL_FIELDS if key in entries}
        if known.get("attempts") is not None:
            known["attempts"] = tuple(AttemptSummary(*a) for a in known["attempts"])
        extra = {key: value for key, value in entries.items() if key not in _DETAIL_FIELDS}
        return cls(**known, extra=extra)

    def replace(self, **changes: Any) -> SolveDetails:
        """Return a copy with fields (or ``extra`` entries, for other names) changed."""
        known = {key: value for key, value in changes.items() if key in _DETAIL_FIELDS}
        other = {key: value for key, value in changes.items() if key not in _DETAIL_FIELDS}
        if other:
            known["extra"] = {**self.extra, **other}
        return dataclasses.replace(self, **known)

    def __getitem__(self, key: str) -> Any:
        """Return a reported field or an ``extra`` entry (``KeyError`` if not reported)."""
        if key in _DETAIL_FIELDS:
            value = getattr(self, key)
            if value is None:
                raise KeyError(key)
            return value
        return self.extra[key]

    def __iter__(self) -> Iterator[str]:
        """Iterate over the names of the reported fields, then the ``extra`` entries."""
        yield from (key for key in _DETAIL_FIELDS if getattr(self, key) is not None)
        yield from self.extra

    def __len__(self) -> int:
        """Return the number of reported entries."""
        return sum(getattr(self, key) is not None for key in _DETAIL_FIELDS) + len(self.extra)

    def __repr__(self) -> str:
        """Show the reported entries."""
        return f"SolveDetails({dict(self)!r})"
