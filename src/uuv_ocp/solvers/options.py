"""Declared solver options: one source of truth for the backends, their errors and the docs.

A backend declares its options as a frozen dataclass whose fields are made by :func:`option`
(default, accepted values, unit, one-line description and a validator), and reads its
``options`` dict with the one generic :func:`parse_options`, which refuses an option the
dataclass does not declare (so the backend does not honour) and validates every given value,
naming ``options['<name>'] of '<solver>'``, before anything is built.  :func:`declaration`
turns the dataclass into :class:`Option` rows: the backend's ``OPTIONS``, which the tables of
``docs/solvers.md`` are rendered from (:func:`uuv_ocp.solvers.catalog.options_table`, called by
the mkdocs hook ``docs/hooks/solver_options.py``), so the documented default *is* the one used.
This module is below the registry (every backend imports it); what reads a declaration by a
registered name lives above it, in :mod:`uuv_ocp.solvers.catalog`.

How a backend declares its options (e.g. :mod:`uuv_ocp.solvers.slsqp`)::

    @dataclasses.dataclass(frozen=True)
    class SlsqpOptions(ChainOptions):  # the options every NlpSolver honours, and its own
        tol: float = option(1e-11, "float > 0", "SLSQP's `ftol`", check=positive_float)


    class SlsqpSolver(NlpSolver):
        Options = SlsqpOptions  # what NlpSolver.__init__ parses options into
        OPTIONS = declaration(SlsqpOptions)  # what catalog.declared_options() and the docs read
        option_names = option_names(OPTIONS)  # the keys the unknown-option error lists

Then add a marker ``<!-- solver-options: slsqp -->`` where its section of ``docs/solvers.md``
lists the options; the hook replaces it by the table.  The registry finds a declaration as the
``OPTIONS`` attribute of the registered factory (a class attribute, or an attribute set on a
factory function: :func:`~uuv_ocp.solvers.swarm.swarm_factory`); ``tests/solvers/test_options.py``
fails for a registered backend without one, for a default the backend does not hold, and for an
Options dataclass that is not its declaration.  A computed declaration (the swarms': population
and iterations are each algorithm's) becomes a dataclass by :func:`make_options_class`.

A default the backend works out when it is built (from the machine, the environment or
another option) is :data:`AUTO` with a ``meaning`` saying how, and the constructor replaces
:data:`AUTO` by that value (``value = rule() if value is AUTO else value``;
``expected_held`` of ``tests/solvers/test_options.py`` computes each rule independently, so a
new one needs a line there); a ``None`` default has a ``meaning`` too (what ``None`` stands
for).
"""

from __future__ import annotations

import copy
import dataclasses
import math
import re
from collections.abc import Callable, Mapping, Sequence
from typing import Any, TypeVar

import numpy as np

from uuv_ocp import _validation

T = TypeVar("T")

__all__ = [
    "AUTO",
    "Option",
    "declaration",
    "format_value",
    "one_of",
    "option",
    "option_defaults",
    "option_names",
    "make_options_class",
    "parse_options",
    "revise",
]


class _Auto:
    """Type of :data:`AUTO` (a single instance; private so no user value equals it)."""

    _instance: _Auto | None = None

    def __new__(cls) -> _Auto:
        if cls._instance is None:
            cls._instance = super().__new__(cls)
        return cls._instance

    def __repr__(self) -> str:
        return "auto"

    def __deepcopy__(self, memo: dict) -> _Auto:
        return self


AUTO = _Auto()
"""A default worked out when the backend is built; the option's ``meaning`` says how."""

_NAME = re.compile(r"[a-z][a-z0-9_]*\Z")


@dataclasses.dataclass(frozen=True)
class Option:
    """One option of a backend's ``options`` dict.

    Parameters
    ----------
    name : str
        The key in ``options`` (lower-case identifier).
    default : object
        The value the constructor uses when the key is absent (:data:`AUTO`: worked out when
        the backend is built, see ``meaning``).  Mutable defaults are copied for every backend
        (:func:`option_defaults`).
    kind : str
        Accepted values, as Markdown (e.g. ``"float > 0"``, :func:`one_of`).
    description : str
        One line, Markdown.
    unit : str
        Physical unit of the value (``""``: none).
    meaning : str
        What a ``None`` or :data:`AUTO` default stands for (required for those), or a note on
        the default; shown next to it.
    """

    name: str
    default: Any
    kind: str
    description: str
    unit: str = ""
    meaning: str = ""

    def __post_init__(self) -> None:
        """Check the fields (a declaration error is the backend author's, raised at import)."""
        if not isinstance(self.name, str) or not _NAME.match(self.name):
            raise ValueError(f"Option.name must be a lower-case identifier, got {self.name!r}")
        for field in ("kind", "description"):
            text = getattr(self, field)
            if not isinstance(text, str) or not text.strip() or "\n" in text:
                raise ValueError(f"Option.{field} of {self.name!r} must be one non-empty line, got {text!r}")
        for field in ("unit", "meaning"):
            text = getattr(self, field)
            if not isinstance(text, str) or "\n" in text:
                raise ValueError(f"Option.{field} of {self.name!r} must be one line, got {text!r}")
        if (self.default is None or self.default is AUTO) and not self.meaning:
            raise ValueError(
                f"Option {self.name!r} has default {self.default!r}: its meaning must say what it stands for"
            )


def one_of(values: Sequence[object]) -> str:
    """Markdown list of the accepted values, e.g. ``one_of(("a", "b"))`` -> ```"a"` or `"b"```."""
    shown = [f"`{format_value(v)}`" for v in values]
    if len(shown) < 2:
        return "".join(shown)
    return f"{', '.join(shown[:-1])} or {shown[-1]}"


def option_names(options: Sequence[Option]) -> tuple[str, ...]:
    """Sorted names of a declaration (a backend's ``option_names``); duplicates are an error."""
    names = [option.name for option in options]
    if len(set(names)) != len(names):
        twice = sorted({name for name in names if names.count(name) > 1})
        raise ValueError(f"options declared twice: {twice}")
    return tuple(sorted(names))


def option_defaults(options: Sequence[Option]) -> dict[str, Any]:
    """``{name: default}`` of a declaration, mutable defaults copied (no backend shares one)."""
    return {option.name: copy.deepcopy(option.default) for option in options}


def revise(options: Sequence[Option], **changes: Mapping[str, Any]) -> tuple[Option, ...]:
    """Return ``options`` with fields of the named ones replaced, order kept.

    ``revise(NLP_OPTIONS, objective_scale={"default": 1e-3})``: a subclass's own default.
    """
    known = {option.name for option in options}
    unknown = sorted(set(changes) - known)
    if unknown:
        raise ValueError(f"revise: no declared option {unknown}; declared: {sorted(known)}")
    return tuple(dataclasses.replace(o, **changes[o.name]) if o.name in changes else o for o in options)


# ------------------------------------------------------------------------------ rendering


def _number(value: float) -> str:
    """Return a short valid Python literal: ``0.0``, ``0.5``, ``100.0``, ``1e-7``, ``1e4``."""
    if value == 0.0 or (1e-3 <= abs(value) < 1e4):
        return repr(value)
    mantissa, exponent = f"{value:.6e}".split("e")
    mantissa = mantissa.rstrip("0").rstrip(".")
    return f"{mantissa}e{int(exponent)}"


def format_value(value: object) -> str:
    """Python-like text of an option value: ``"sticky"``, ``1e-7``, ``(100, 1e4)``, ``{}``."""
    if isinstance(value, str):
        return f'"{value}"'
    if isinstance(value, bool) or value is None or value is AUTO:
        return repr(value)
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        return _number(value) if math.isfinite(value) else repr(value)
    if isinstance(value, tuple | list):
        inner = ", ".join(format_value(v) for v in value)
        if isinstance(value, tuple):
            return f"({inner},)" if len(value) == 1 else f"({inner})"
        return f"[{inner}]"
    if isinstance(value, Mapping):
        return "{" + ", ".join(f"{format_value(k)}: {format_value(v)}" for k, v in value.items()) + "}"
    return repr(value)


def default_cell(option: Option) -> str:
    """Markdown of an option's default: the value in code, then what it means."""
    text = "auto" if option.default is AUTO else f"`{format_value(option.default)}`"
    return f"{text}: {option.meaning}" if option.meaning else text


# ------------------------------------------------------------------ options as dataclasses

Check = Callable[[str, Any], Any]
"""A validator ``check(label, value) -> value``: the accepted value, or ``ValueError`` naming ``label``."""


@dataclasses.dataclass(frozen=True)
class _Declared:
    """What :func:`option` attaches to a dataclass field: the docs' columns and the validator."""

    kind: str
    description: str
    unit: str
    meaning: str
    check: Check | None


def option(
    default: Any,
    kind: str,
    description: str,
    *,
    unit: str = "",
    meaning: str = "",
    check: Check | None = None,
) -> Any:
    """Declare one field of a backend's options dataclass (see :func:`parse_options`).

    ``default``, ``kind``, ``description``, ``unit`` and ``meaning`` are those of
    :class:`Option` (the docs' table); ``check(label, value)`` validates a given value and
    returns it (``ValueError`` naming ``label`` otherwise; ``None``: any value).  A mutable
    default is copied for every instance.
    """
    Option("checked", default, kind, description, unit, meaning)  # the declaration's own checks
    metadata = {"option": _Declared(kind, description, unit, meaning, check)}
    if isinstance(default, dict | list | set):
        return dataclasses.field(default_factory=lambda: copy.deepcopy(default), metadata=metadata)
    return dataclasses.field(default=default, metadata=metadata)


def _declared_fields(options_class: type) -> list[dataclasses.Field]:
    if not (isinstance(options_class, type) and dataclasses.is_dataclass(options_class)):
        raise TypeError(f"options class must be a dataclass, got {options_class!r}")
    fields = dataclasses.fields(options_class)
    missing = [f.name for f in fields if "option" not in f.metadata]
    if missing:
        raise TypeError(f"{options_class.__name__}: fields {missing} are not declared with option()")
    return list(fields)


def declaration(options_class: type) -> tuple[Option, ...]:
    """Return the :class:`Option` rows of an options dataclass (what the docs' tables render)."""
    rows = []
    for f in _declared_fields(options_class):
        meta: _Declared = f.metadata["option"]
        default = f.default_factory() if f.default is dataclasses.MISSING else f.default  # type: ignore[operator]
        rows.append(Option(f.name, default, meta.kind, meta.description, meta.unit, meta.meaning))
    return tuple(rows)


def parse_options(
    options_class: type[T],
    options: Mapping[str, Any] | None,
    solver: str,
    valid: Sequence[str] | None = None,
) -> T:
    """Return ``options_class(**options)`` with every given value validated, before any build.

    The one parser of every backend's ``options`` dict: an option the backend does not
    declare (so does not honour) is refused, as is a value its field's ``check`` refuses.
    ``valid``: the names the error lists (default: the fields; a subclass that read options
    of its own before passing the rest here lists all of them).

    Raises
    ------
    ValueError
        ``options`` is not a dict; an unknown name (the message lists the valid ones); a value
        out of its range (the message names ``options['<name>']``).
    """
    if options is None:
        options = {}
    if not isinstance(options, Mapping):
        raise ValueError(f"options of solver {solver!r} must be a dict or None, got {shown_type(options)}")
    fields = _declared_fields(options_class)
    names = [f.name for f in fields]
    unknown = sorted(set(options) - set(names))
    if unknown:
        listed = sorted(names if valid is None else valid)
        raise ValueError(f"unknown options for solver {solver!r}: {unknown}; valid: {listed}")
    values = {}
    for f in fields:
        if f.name in options:
            check = f.metadata["option"].check
            value = options[f.name]
            label = f"options[{f.name!r}] of {solver!r}"  # names the parameter and the backend
            # the declared AUTO default handed back (option_defaults) means the same as absent
            automatic = value is AUTO and f.default is AUTO
            values[f.name] = value if check is None or automatic else check(label, value)
    return options_class(**values)


def make_options_class(name: str, rows: Sequence[Option], checks: Mapping[str, Check]) -> type:
    """Return a frozen options dataclass made of :class:`Option` rows, each with its validator.

    For backends whose declaration is computed (the swarms: population and iterations are each
    algorithm's); ``checks`` needs one validator per row.
    """
    missing = sorted({row.name for row in rows} - set(checks))
    if missing:
        raise ValueError(f"make_options_class {name!r}: no check for {missing}")
    fields = [
        (
            row.name,
            Any,
            option(
                row.default,
                row.kind,
                row.description,
                unit=row.unit,
                meaning=row.meaning,
                check=checks[row.name],
            ),
        )
        for row in rows
    ]
    return dataclasses.make_dataclass(name, fields, frozen=True)


def shown_type(value: object) -> str:
    """Name of ``value``'s type, for messages."""
    return type(value).__name__


# validators for option(check=...); each is check(label, value) -> value


def optional(check: Check) -> Check:
    """``None`` or what ``check`` accepts."""

    def checked(label: str, value: Any) -> Any:
        return None if value is None else check(label, value)

    return checked


def among(values: Sequence[str]) -> Check:
    """One of ``values`` (the message lists them)."""

    def checked(label: str, value: Any) -> Any:
        return _validation.choice(label, value, values)

    return checked


def mapping(label: str, value: Any) -> dict:
    """Accept a dict (returned copied)."""
    if not isinstance(value, dict):
        raise ValueError(f"{label} must be a dict, got {_validation.shown(value)}")
    return dict(value)


def factors(label: str, value: Any) -> tuple[float, ...]:
    """Accept a tuple of floats > 0 (a list or an array is made a tuple)."""
    if not isinstance(value, tuple | list | np.ndarray):
        raise ValueError(
            f"{label} must be a tuple of factors > 0, e.g. (100.0, 1e4), got {_validation.shown(value)}"
        )
    return tuple(_validation.positive_float(f"{label} entries", factor) for factor in value)


positive_float: Check = _validation.positive_float
nonnegative_float: Check = _validation.nonnegative_float
positive_int: Check = _validation.positive_int
boolean: Check = _validation.boolean
