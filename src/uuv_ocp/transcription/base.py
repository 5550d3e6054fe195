"""The transcription strategy: how one control interval's dynamics enter the NLP and the rollout.

:func:`~uuv_ocp.transcription.multiple_shooting.transcribe` writes one stage loop for every
strategy; a strategy says only what differs on an interval: the variables it adds between the
control ``z_k`` and the next state ``X_{k+1}`` (none for multiple shooting, the collocation
states for collocation), the equality rows on them, the end state ``X_{k+1}`` must equal, the
step ``F(x_k, u_k)`` the condensed form (rollouts, swarms, the judge) uses, and a starting guess
for its variables.  Both forms describe one discretisation: where the rows hold, the end state is
``F(x_k, u_k)``.

A new strategy is one class registered with :func:`register_transcription`; an
:class:`~uuv_ocp.ocp.Ocp` then takes it by name (``Ocp(..., transcription="mine")``).
"""

from __future__ import annotations

import threading
from typing import TYPE_CHECKING, Protocol, runtime_checkable

import casadi as ca
import numpy as np

from uuv_ocp.integrators import rk4_step

if TYPE_CHECKING:
    from uuv_ocp.ocp import OcpSpec


@runtime_checkable
class Transcription(Protocol):
    """What one stage loop asks of a transcription (module doc)."""

    #: name an Ocp chooses it by
    name: str
    #: key kinds of its interval variables and of its rows (``(kind, stage, index)``)
    variable_kind: str
    row_kind: str

    def check_degree(self, degree: object, substeps: int) -> int:
        """Validate the Ocp's ``degree`` (and ``substeps``) for this strategy; 0 if it takes none."""
        ...

    def step(self, spec: OcpSpec) -> ca.Function:
        """Return the condensed form's ``F: (x, u, p_stage, p_global) -> x_next``."""
        ...

    def interval_size(self, spec: OcpSpec) -> int:
        """Return the number of variables it adds per interval."""
        ...

    def interval(
        self,
        spec: OcpSpec,
        step: ca.Function,
        variables: ca.SX,
        state: ca.SX,
        control: ca.SX,
        p_stage: ca.SX,
        p_global: ca.SX,
    ) -> tuple[ca.SX, ca.SX]:
        """Return ``(rows, end_state)`` of one interval: equality rows (= 0) and the state at its end."""
        ...

    def interval_guess(self, spec: OcpSpec, states: np.ndarray) -> np.ndarray:
        """Return starting values ``(N, interval_size)`` of the interval variables along ``states``."""
        ...


class MultipleShooting:
    """Multiple shooting: ``X_{k+1} = F(x_k, u_k)`` with ``F`` RK4 of ``substeps`` steps."""

    name = "multiple_shooting"
    variable_kind = "interval"
    row_kind = "interval"

    def check_degree(self, degree: object, substeps: int) -> int:
        """Refuse a degree: multiple shooting has none."""
        if degree is not None:
            raise ValueError(
                f"degree is for transcription='collocation', got degree={degree!r} with multiple shooting"
            )
        return 0

    def step(self, spec: OcpSpec) -> ca.Function:
        """RK4 with ``spec.substeps`` steps per interval."""
        return rk4_step(spec.dynamics, spec.dt, spec.substeps, name="model_step")

    def interval_size(self, spec: OcpSpec) -> int:
        """No interval variables."""
        return 0

    def interval(
        self,
        spec: OcpSpec,
        step: ca.Function,
        variables: ca.SX,
        state: ca.SX,
        control: ca.SX,
        p_stage: ca.SX,
        p_global: ca.SX,
    ) -> tuple[ca.SX, ca.SX]:
        """No rows; the end state is the step's."""
        return ca.SX(0, 1), step(state, control, p_stage, p_global)

    def interval_guess(self, spec: OcpSpec, states: np.ndarray) -> np.ndarray:
        """Nothing to guess."""
        return np.zeros((len(states) - 1, 0))


_LOCK = threading.Lock()
_TRANSCRIPTIONS: dict[str, Transcription] = {}


def register_transcription(strategy: Transcription, *, overwrite: bool = False) -> None:
    """Make ``strategy`` available to :class:`~uuv_ocp.ocp.Ocp` by its ``name``.

    Raises
    ------
    TypeError
        ``strategy`` does not implement :class:`Transcription`.
    ValueError
        The name is taken (``overwrite=False``).
    """
    if not isinstance(strategy, Transcription):
        raise TypeError(
            f"strategy must implement uuv_ocp.transcription.base.Transcription, got {type(strategy).__name__}"
        )
    with _LOCK:
        if strategy.name in _TRANSCRIPTIONS and not overwrite:
            raise ValueError(f"transcription {strategy.name!r} is registered already (pass overwrite=True)")
        _TRANSCRIPTIONS[strategy.name] = strategy


def transcription(name: str) -> Transcription:
    """Return the registered strategy ``name`` (``ValueError`` naming the registered ones)."""
    with _LOCK:
        strategy = _TRANSCRIPTIONS.get(name) if isinstance(name, str) else None
        if strategy is None:
            raise ValueError(f"transcription must be one of {sorted(_TRANSCRIPTIONS)}, got {name!r}")
        return strategy


def transcription_names() -> tuple[str, ...]:
    """Names of the registered strategies."""
    with _LOCK:
        return tuple(_TRANSCRIPTIONS)


register_transcription(MultipleShooting())
