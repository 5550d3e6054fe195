"""The one explicit, cached build step: an Ocp description -> the CasADi objects solvers share.

:class:`Transcribed` is what every backend sees of a problem (an :class:`~uuv_ocp.ocp.Ocp`
or a preset such as :class:`~uuv_ocp.tracking.TrackingProblem`): dimensions, the parameter
vector, the built NLP variants and condensed Functions, and conversions between physical and
scaled controls.  Nothing is built in a constructor: :meth:`Transcribed.build` builds on first
use and keeps the result in one package-level cache keyed by the problem's content digest
(``OcpSpec.key``): two equal problems share one build, and a problem that is changed (a new
object) is never served a stale build.  The cache is thread-safe (a build runs once, under
:data:`uuv_ocp._concurrency.BUILD_LOCK`) and bounded: it keeps the :data:`BUILD_CACHE_SIZE`
builds used last and drops the oldest (whoever holds a dropped build keeps using it; the next
``build()`` of its problem builds again).  A :class:`Built` holds only CasADi Functions and
expressions, never evaluation memory: every caller evaluates through buffers of its own
(:meth:`Transcribed.buffered`: one per thread).  Compiled native code is cached on disk by the
digest of its generated source (:mod:`uuv_ocp.native.compile`), so equal problems share it across
objects and processes.
"""

from __future__ import annotations

import threading
from collections import OrderedDict
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import casadi as ca
import numpy as np

from uuv_ocp import _validation as check
from uuv_ocp._concurrency import BUILD_LOCK, BuildCache
from uuv_ocp.integrators import rk4_step
from uuv_ocp.native.buffered import BufferedFunction
from uuv_ocp.transcription.condensed import condense, decode
from uuv_ocp.transcription.multiple_shooting import NlpData, transcribe

if TYPE_CHECKING:
    from uuv_ocp.ocp import OcpSpec


@dataclass
class Built:
    """CasADi objects of one problem: the integrator step, NLP variants, condensed Functions."""

    spec: OcpSpec
    step: ca.Function
    hard: NlpData
    cost: ca.Function
    rollout: ca.Function
    score_terms: ca.Function
    decode: ca.Function
    _soft: dict[float, NlpData] = field(default_factory=dict, repr=False)

    @property
    def soft(self) -> NlpData | None:
        """The exact-penalty terminal relaxation at the problem's ``terminal_penalty``."""
        return self.soft_variant(self.spec.terminal_penalty)

    def soft_variant(self, terminal_penalty: float) -> NlpData | None:
        """Return the terminal relaxation with L1 weight ``terminal_penalty`` (``None``: no equality)."""
        if not self.spec.has_terminal_equality:
            return None
        if terminal_penalty not in self._soft:
            with BUILD_LOCK:  # a build is shared by threads: one of them transcribes it
                if terminal_penalty not in self._soft:
                    self._soft[terminal_penalty] = transcribe(self.spec, self.step, True, terminal_penalty)
        return self._soft[terminal_penalty]


#: Most builds :meth:`Transcribed.build` keeps (the least recently used is dropped first).
BUILD_CACHE_SIZE = 32
#: Most zero-copy callers :meth:`Transcribed.buffered` keeps per thread (oldest dropped first).
BUFFERED_PER_THREAD = 64

_BUILDS: BuildCache[Built] = BuildCache(BUILD_CACHE_SIZE)
_THREAD = threading.local()  # .callers: this thread's BufferedFunctions by (spec key, name)


def build_spec(spec: OcpSpec) -> Built:
    """Transcribe ``spec`` (multiple shooting + condensed, one RK4 Function for both)."""
    step = rk4_step(spec.dynamics, spec.dt, spec.substeps, name="model_step")
    hard = transcribe(spec, step, False, spec.terminal_penalty)
    cost, rollout, score_terms = condense(spec, step)
    return Built(
        spec=spec,
        step=step,
        hard=hard,
        cost=cost,
        rollout=rollout,
        score_terms=score_terms,
        decode=decode(spec),
    )


class Transcribed:
    """What solvers use of a problem; subclasses provide :meth:`spec` and ``_store``."""

    _store: dict[Any, Any]

    def spec(self) -> OcpSpec:
        """Return the frozen description of the problem."""
        raise NotImplementedError

    # ---------------------------------------------------------------- building
    def build(self) -> Built:
        """Build (once per content, on first use) and return the CasADi objects all solvers share.

        Kept in the package's build cache (module doc): equal problems share one build.
        """
        spec = self.spec()
        return _BUILDS.get(spec.key, lambda: build_spec(spec))

    def buffered(self, name: str) -> BufferedFunction:
        """Zero-copy caller of the built Function ``name`` (``"rollout"``, ``"score_terms"``, …).

        The calling thread's own caller (its buffers are written by every call): a caller is
        never shared between threads.
        """
        callers: OrderedDict[tuple[str, str], BufferedFunction] | None = getattr(_THREAD, "callers", None)
        if callers is None:
            callers = _THREAD.callers = OrderedDict()
        key = (self.spec().key, name)
        caller = callers.get(key)
        if caller is None:
            caller = callers[key] = BufferedFunction(getattr(self.build(), name))
            if len(callers) > BUFFERED_PER_THREAD:
                callers.popitem(last=False)
        return caller

    # -------------------------------------------------------------- dimensions
    @property
    def state_dim(self) -> int:
        """Number of scalar states."""
        return self.spec().state_dim

    @property
    def control_size(self) -> int:
        """Number of scalar controls per interval."""
        return self.spec().control_size

    @property
    def control_dim(self) -> int:
        """Number of decision controls of the condensed problem, ``nu · N``."""
        spec = self.spec()
        return spec.control_size * spec.horizon

    @property
    def parameter_dim(self) -> int:
        """Length of the parameter vector ``p``."""
        return self.spec().layout.size

    @property
    def soft_terminal_available(self) -> bool:
        """Whether a hard terminal equality exists (and with it the exact-penalty fallback)."""
        return self.spec().has_terminal_equality

    @property
    def still_water_slice(self) -> slice | None:
        """Part of ``p`` whose exact zero lets exact backends specialise the NLP (or ``None``)."""
        return None

    # ----------------------------------------------------------- conversions
    def controls_from_scaled(self, scaled: np.ndarray) -> np.ndarray:
        """Scaled controls ``(nu N,)`` or ``(N, nu)`` -> physical ``(N, nu)``."""
        spec = self.spec()
        return spec.physical(np.reshape(scaled, (spec.horizon, spec.control_size)))

    def scaled_from_controls(self, controls: object) -> np.ndarray:
        """Physical controls ``(N, nu)`` -> flat scaled vector ``(nu N,)``."""
        spec = self.spec()
        controls = check.finite_array("controls", controls, (spec.horizon, spec.control_size))
        return spec.scaled(controls).ravel()

    def rollout_scaled(
        self, scaled: np.ndarray, p: np.ndarray, rollout: BufferedFunction | None = None
    ) -> np.ndarray:
        """States ``(N+1, nx)`` under flat scaled controls ``(nu N,)`` (no validation: hot path)."""
        (states,) = (rollout or self.buffered("rollout"))(scaled, p)
        return states.reshape(self.spec().horizon + 1, self.spec().state_dim)

    def rollout(self, controls: object, p: np.ndarray) -> np.ndarray:
        """States ``(N+1, nx)`` from the prediction model under physical ``controls`` (N, nu)."""
        return self.rollout_scaled(self.scaled_from_controls(controls), p)

    def with_state(self, p: np.ndarray, x0: object) -> np.ndarray:
        """Return a copy of the instance ``p`` with its state set to ``x0`` (checked as ``x0``).

        For an :class:`~uuv_ocp.ocp.Ocp` the state enters ``p`` only at its own place, so this
        is ``parameters`` at ``x0`` with the other arguments of ``p``; a tracking problem also
        moves its reference heading's branch (``TrackingProblem.with_state``).
        """
        spec = self.spec()
        new = p.copy()
        new[spec.layout.x0] = check.plausible_array("x0", x0, (spec.state_dim,))
        return new

    def previous_scaled(self, p: np.ndarray) -> np.ndarray:
        """Return the last applied control in ``p``, scaled and clipped into the box."""
        spec = self.spec()
        scaled = spec.scaled(np.asarray(p[spec.layout.u_prev], dtype=float))
        return np.clip(scaled, spec.scaled_lower, spec.scaled_upper)

    def initial_guess(self, p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Cold-start plan ``(states (N+1, nx), scaled controls (N, nu))`` for instance ``p``.

        The default holds ``x_0`` and the last applied control over the horizon.
        """
        spec = self.spec()
        states = np.tile(np.asarray(p[spec.layout.x0], dtype=float), (spec.horizon + 1, 1))
        return states, np.tile(self.previous_scaled(p), (spec.horizon, 1))
