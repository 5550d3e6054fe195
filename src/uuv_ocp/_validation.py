"""Input checks shared by every public entry point.

Each helper raises :class:`ValueError` naming the parameter, what was expected and what came,
so that bad input is rejected before any solver runs.
"""

from __future__ import annotations

import math
import numbers
import reprlib
from collections.abc import Sequence

import numpy as np

_SHORT = reprlib.Repr()
_SHORT.maxstring = 80
_SHORT.maxother = 80
_SHORT.maxlist = _SHORT.maxtuple = 8
#: up to this many entries :func:`within` compares Python floats (one conversion) instead of
#: calling three ufuncs, whose dispatch costs several times more on the small vectors checked
#: at every closed-loop step
SMALL_ARRAY = 16
#: a bound of :func:`within`: one real number, or one per entry
Bound = float | Sequence[float] | np.ndarray


def within(values: np.ndarray, lower: Bound, upper: Bound) -> bool:
    """Whether every entry of ``values`` lies in ``[lower, upper]`` (NaN does not).

    ``lower`` and ``upper``: one real number for every entry, or one per entry (a list or an
    array of ``values.size`` numbers, flat order; another size raises ``ValueError``).
    """
    flat = values.ravel()
    if flat.size > SMALL_ARRAY:
        low, high = np.ravel(np.asarray(lower, dtype=float)), np.ravel(np.asarray(upper, dtype=float))
        for bound in (low, high):
            if bound.size not in (1, flat.size):
                raise ValueError(f"within: {bound.size} bounds for {flat.size} values")
        return bool(((flat >= low) & (flat <= high)).all())
    entries = flat.tolist()
    lows, highs = _per_entry(lower, len(entries)), _per_entry(upper, len(entries))
    return all(low <= value <= high for value, low, high in zip(entries, lows, highs, strict=True))


def _per_entry(bound: Bound, size: int) -> list[float]:
    """``bound`` as ``size`` floats: a float or a list of them as they come (the hot path)."""
    if isinstance(bound, float):
        return [bound] * size
    if isinstance(bound, list) and len(bound) == size:
        return bound
    array = np.asarray(bound, dtype=float)
    if array.ndim == 0:
        return [float(array)] * size
    return array.ravel().tolist()


def shown(value: object) -> str:
    """Short text of ``value`` for an error message: numbers plainly, never numpy reprs.

    ``np.float64(0.5)`` reads ``0.5``, an array ``[0.5, 1.0]``, and long values are cut
    (``...``).
    """
    if isinstance(value, np.generic):
        value = value.item()
    if isinstance(value, np.ndarray):
        if value.size > 12:
            return f"array of shape {value.shape}"
        value = value.tolist()
    if isinstance(value, list | tuple) and any(isinstance(v, np.generic) for v in value):
        items = [v.item() if isinstance(v, np.generic) else v for v in value]
        value = items if isinstance(value, list) else tuple(items)
    return _SHORT.repr(value)


def positive_float(name: str, value: object) -> float:
    """Return ``value`` as a float if it is finite and > 0, else raise ``ValueError``."""
    number = finite_float(name, value)
    if number <= 0.0:
        raise ValueError(f"{name} must be a finite number > 0, got {shown(value)}")
    return number


def nonnegative_float(name: str, value: object) -> float:
    """Return ``value`` as a float if it is finite and >= 0, else raise ``ValueError``."""
    number = finite_float(name, value)
    if number < 0.0:
        raise ValueError(f"{name} must be a finite number >= 0, got {shown(value)}")
    return number


def finite_float(name: str, value: object) -> float:
    """Return ``value`` as a float if it is a finite real number, else raise ``ValueError``."""
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise ValueError(f"{name} must be a real number, got {shown(value)}")
    number = float(value)
    if not math.isfinite(number):
        raise ValueError(f"{name} must be finite, got {shown(value)}")
    return number


def boolean(name: str, value: object) -> bool:
    """Return ``value`` if it is ``True`` or ``False``, else raise ``ValueError``."""
    if not isinstance(value, bool):
        raise ValueError(f"{name} must be True or False, got {shown(value)}")
    return value


def positive_int(name: str, value: object, minimum: int = 1) -> int:
    """Return ``value`` if it is an integer >= ``minimum`` (bools rejected), else raise."""
    if isinstance(value, bool) or not isinstance(value, numbers.Integral):
        raise ValueError(f"{name} must be an integer >= {minimum}, got {shown(value)}")
    if int(value) < minimum:
        raise ValueError(f"{name} must be an integer >= {minimum}, got {shown(value)}")
    return int(value)


def vector(
    name: str,
    value: object,
    length: int,
    *,
    positive: bool = False,
    nonnegative: bool = False,
) -> tuple[float, ...]:
    """Return ``value`` as a tuple of ``length`` finite floats, checking the sign if asked."""
    # numpy would read the text "1" as the number 1.0: text is no number here
    if isinstance(value, str | bytes) or (
        isinstance(value, list | tuple) and any(isinstance(v, str | bytes) for v in value)
    ):
        raise ValueError(f"{name} must be {length} real numbers, got {shown(value)}")
    try:
        array = np.asarray(value, dtype=float)
    except (TypeError, ValueError) as error:
        raise ValueError(f"{name} must be {length} real numbers, got {shown(value)}") from error
    if array.shape != (length,):
        raise ValueError(f"{name} must have shape ({length},), got shape {array.shape}: {shown(value)}")
    if not np.all(np.isfinite(array)):
        raise ValueError(f"{name} must be finite, got {shown(value)}")
    if positive and np.any(array <= 0.0):
        raise ValueError(f"{name} must be > 0 element-wise, got {shown(value)}")
    if nonnegative and np.any(array < 0.0):
        raise ValueError(f"{name} must be >= 0 element-wise, got {shown(value)}")
    return tuple(float(v) for v in array)


def finite_array(name: str, value: object, shape: Sequence[int | None]) -> np.ndarray:
    """Return ``value`` as a float array of ``shape`` with finite entries (``None``: any size there)."""
    expected = tuple(shape)
    wanted = "(" + ", ".join("k" if n is None else str(n) for n in expected)
    wanted += ",)" if len(expected) == 1 else ")"
    try:
        array = np.array(value, dtype=float)
    except (TypeError, ValueError) as error:
        raise ValueError(f"{name} must be a real array of shape {wanted}, got {shown(value)}") from error
    if array.ndim != len(expected) or any(
        n is not None and a != n for a, n in zip(array.shape, expected, strict=True)
    ):
        raise ValueError(f"{name} must have shape {wanted}, got shape {array.shape}")
    if not np.all(np.isfinite(array)):
        raise ValueError(f"{name} must be finite (no NaN or inf), got {shown(array)}")
    return array


#: Largest magnitude accepted for an entry of an initial state ``x0`` (or a current): a
#: plausibility bound, far beyond any vehicle (1e9 m is 25 times round the Earth; UTM
#: coordinates stay below 1e7 m) but low enough that squared errors stay finite in float64.
#: Beyond it the input is a unit or sign mistake, not a state: ``ValueError``.
PLAUSIBLE_MAGNITUDE = 1e9


def plausible_array(name: str, value: object, shape: Sequence[int]) -> np.ndarray:
    """Like :func:`finite_array`, and every entry within ``±PLAUSIBLE_MAGNITUDE``."""
    # the closed loop's hot path checks x0 and the current every step: one comparison accepts
    # a good value (NaN and ±inf fail ``<=``); anything else takes the checks below for the error
    try:
        array = np.array(value, dtype=float)
    except (TypeError, ValueError):
        pass
    else:
        if array.shape == tuple(shape) and within(array, -PLAUSIBLE_MAGNITUDE, PLAUSIBLE_MAGNITUDE):
            return array
    array = finite_array(name, value, shape)
    outside = np.abs(array) > PLAUSIBLE_MAGNITUDE
    if np.any(outside):
        index = tuple(int(i) for i in np.argwhere(outside)[0])
        where = index[0] if len(index) == 1 else index
        raise ValueError(
            f"{name} must have every entry within ±{PLAUSIBLE_MAGNITUDE:g} (a plausibility bound), "
            f"got {float(array[index]):g} at index {where}"
        )
    return array


#: Smallest mass or moment of inertia accepted for a vehicle (kg, kg·m²): below it the
#: accelerations ``τ / m`` of a full thrust overflow float64 once squared in a cost.
SMALLEST_INERTIA = 1e-6


def plausible_parameter(
    name: str, value: float | Sequence[float], unit: str, *, minimum: float | None = None
) -> None:
    """Raise ``ValueError`` unless every entry of ``value`` (already finite) lies in the plausible range.

    The range is ``|entry| <= PLAUSIBLE_MAGNITUDE`` (1e9: a million tonnes, a giganewton),
    and ``entry >= minimum`` if given.  ``mass=1e308`` was accepted and its solve "succeeded"
    with zero accelerations; such a value is a unit or typing mistake, not a vehicle.
    """
    entries = [value] if isinstance(value, int | float) else list(value)
    for index, entry in enumerate(entries):
        where = "" if len(entries) == 1 and isinstance(value, int | float) else f" (entry {index})"
        if abs(entry) > PLAUSIBLE_MAGNITUDE:
            raise ValueError(
                f"{name} must be at most {PLAUSIBLE_MAGNITUDE:g} {unit} in magnitude (a plausibility "
                f"bound of vehicle parameters), got {entry:g}{where}"
            )
        if minimum is not None and entry < minimum:
            raise ValueError(
                f"{name} must be at least {minimum:g} {unit} (a plausibility bound of vehicle "
                f"parameters), got {entry:g}{where}"
            )


def choice(name: str, value: object, allowed: Sequence[str]) -> str:
    """Return ``value`` if it is one of ``allowed``, else raise naming the valid options."""
    if not isinstance(value, str) or value not in allowed:
        raise ValueError(f"{name} must be one of {sorted(allowed)}, got {shown(value)}")
    return str(value)


#: Options that keep a plugin silent while :func:`nlpsol_options` tries the user's options
#: on a one-variable NLP (the user's own entries override them).
_QUIET_PLUGIN_OPTIONS: dict[str, dict] = {
    "ipopt": {"ipopt.print_level": 0, "ipopt.sb": "yes"},
    "fatrop": {"fatrop.print_level": 0},
    "sqpmethod": {
        "print_header": False,
        "print_iteration": False,
        "print_status": False,
        "qpsol": "qrqp",
        "qpsol_options": {"print_iter": False, "print_header": False, "error_on_fail": False},
    },
}
#: Words of CasADi's and the plugins' errors about an option (other errors of the trial NLP,
#: e.g. a structure option that does not fit one variable, are left to the real solve).
_OPTION_ERRORS = ("option", "Option", "type mismatch", "Illegal type", "can_cast_to")


def nlpsol_options(name: str, plugin: str, options: dict) -> None:
    """Raise ``ValueError`` if CasADi's ``plugin`` refuses ``options`` (``nlpsol`` options).

    CasADi checks option names and types when a solver is created, IPOPT its own options
    there too, fatrop its own when it first solves; so the options are tried on a
    one-variable NLP, created and solved once (a few ms, only for non-empty ``options``).  An
    unknown name or a wrong type crashed the first solve with a CasADi traceback before.  The
    message names the first refused entry (each entry is tried alone to find it).
    """
    if not options:
        return
    failure = _nlpsol_failure(plugin, options)
    if failure is None:
        return
    entry, reason = f"{name}", failure
    for key, value in options.items():
        parts = [({key: value}, f"[{key!r}]")]
        if isinstance(value, dict):  # e.g. {"ipopt": {"tol": ...}}: name the nested entry
            parts = [({key: {sub: item}}, f"[{key!r}][{sub!r}]") for sub, item in value.items()] or parts
        for trial, path in parts:
            alone = _nlpsol_failure(plugin, trial)
            if alone is not None:
                (item,) = trial.values()
                if path.count("[") > 1:
                    (item,) = item.values()
                entry, reason = f"{name}{path} = {shown(item)}", alone
                break
        else:
            continue
        break
    raise ValueError(
        f"{entry} is refused by CasADi's {plugin!r} nlpsol plugin: {reason} "
        f"(its options: casadi.doc_nlpsol({plugin!r}))"
    )


def _nlpsol_failure(plugin: str, options: dict) -> str | None:
    """Why ``plugin`` refuses ``options`` on a one-variable NLP (one line), or ``None``."""
    import casadi as ca

    x = ca.SX.sym("x")
    merged = {**_QUIET_PLUGIN_OPTIONS.get(plugin, {}), "print_time": False, "error_on_fail": False}
    if "qpsol" in options or "qpsol_options" in options:  # the quiet QP options are QRQP's
        merged.pop("qpsol_options", None)
    merged.update(options)
    try:
        solver = ca.nlpsol("plugin_options_check", plugin, {"x": x, "f": x**2}, merged)
        solver(x0=1.0)
    except RuntimeError as error:
        text = str(error)
        if not any(word in text for word in _OPTION_ERRORS):
            return None
        return _casadi_reason(text)
    return None


def _casadi_reason(text: str) -> str:
    """Return the informative line of a CasADi error, without source paths and option listings."""
    lines = []
    for line in text.splitlines():
        line = line.strip()
        if (
            not line
            or line.startswith(">")
            or line.startswith("Use print_options")
            or line.startswith("Did you")
        ):
            continue
        # ".../casadi/core/options.cpp:255: Unknown option: bogus" -> "Unknown option: bogus"
        while line.startswith(".../") and ": " in line:
            line = line.split(": ", 1)[1]
        if line.startswith("Error calling") or line.startswith("Error in Function"):
            continue
        lines.append(line)
    useful = [line for line in lines if not line.startswith("Assertion")] or lines
    reason = "; ".join(useful[-2:]) if useful else "refused"
    return "wrong type for this option (type mismatch)" if reason == "type mismatch" else reason
