"""Vehicles and references named by a short text: the vocabulary of the CLI and config files.

A *vehicle spec* is a preset name, a TOML file or ``FILE.py:CLASS`` (a class of yours that
implements the vehicle protocol, called without arguments); a *reference spec* is a paper reference name,
``waypoints FILE``, ``lawnmower FILE``, ``hold X,Y,PSI`` or a TOML file.  Both turn into the same
objects the Python API takes (:class:`~uuv_ocp.model.planar.Vehicle`,
:class:`~uuv_ocp.model.fossen6dof.Vehicle6DOF`, :class:`~uuv_ocp.reference.path.Reference`), so a
campaign config, ``uuv-ocp track --vehicle bluerov2-heavy`` and a script describe one problem in
one way.

Vehicle file (TOML)::

    [vehicle]
    model = "planar"          # "planar" (3-DOF) or "6dof"; implied by a preset
    preset = "rexrov"         # optional: start from a preset and override the fields below
                              # (preset = "remus100" takes the fields of Remus100)
    name = "my-rov"
    mass = 1500.0             # any field of Vehicle / Vehicle6DOF, in its documented units

Reference file (TOML)::

    [reference]
    kind = "waypoints"        # "waypoints" (default), "lawnmower", "hold" or "paper"
    points = [[0, 0], [20, 0], [20, 10]]   # m; three columns for a spatial (6-DOF) path
    speed = 0.5               # m/s
    turn_radius = 2.0         # m
    hold = 10.0               # s at the last waypoint, at rest (default 10)

The other kinds take the keyword arguments of :meth:`Reference.lawnmower`,
:meth:`Reference.hold` (``pose``, ``duration``) and :meth:`Reference.paper` (``name``).  A
waypoint file may also be CSV: one ``x, y[, z]`` row per waypoint (m), ``#`` comments, then
:data:`CSV_SPEED` and :data:`CSV_TURN_RADIUS` apply.
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import importlib.util
import math
import sys
import tomllib
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from uuv_ocp._concurrency import BUILD_LOCK
from uuv_ocp._validation import shown
from uuv_ocp.model.base import check_vehicle
from uuv_ocp.model.fossen6dof import Vehicle6DOF
from uuv_ocp.model.planar import Vehicle
from uuv_ocp.model.remus100 import Remus100
from uuv_ocp.reference.path import PAPER_REFERENCES, Reference
from uuv_ocp.solvers.base import reraise_interrupt

AnyVehicle = Vehicle | Vehicle6DOF | Remus100

#: Vehicle presets by name: 3-DOF planar and 6-DOF Fossen models, and the REMUS 100 torpedo
#: (6-DOF, controls [rudder, stern plane, propeller rpm]).
VEHICLE_PRESETS: dict[str, Callable[[], AnyVehicle]] = {
    "rexrov": Vehicle.rexrov,
    "rexrov-controller": Vehicle.rexrov_controller_model,
    "bluerov2-heavy": Vehicle6DOF.bluerov2_heavy,
    # controls are the thruster forces (allocation in the model): what thruster faults need
    "bluerov2-heavy-thrusters": functools.partial(Vehicle6DOF.bluerov2_heavy, thrusters=True),
    "rexrov2": Vehicle6DOF.rexrov2,
    "rexrov2-thrusters": functools.partial(Vehicle6DOF.rexrov2, thrusters=True),
    "remus100": Remus100,
}
#: Reference kinds a spec or a ``[reference]`` table may name.
REFERENCE_KINDS = ("waypoints", "lawnmower", "hold", "paper")
#: Path speed (m/s) and turn radius (m) of a waypoint CSV file, which holds only positions.
CSV_SPEED = 0.5
CSV_TURN_RADIUS = 1.0
#: Depth (m, z down) at which a paper reference (planar) is flown by a 6-DOF vehicle.
DEFAULT_DEPTH = 5.0
_MODELS: dict[str, type] = {"planar": Vehicle, "6dof": Vehicle6DOF}


def _read_table(path: Path, table: str) -> dict[str, Any]:
    """Read the ``[table]`` of a TOML file; ``ValueError`` names the file and what is wrong."""
    try:
        document = tomllib.loads(path.read_text(encoding="utf-8"))
    except OSError as error:
        raise ValueError(f"{path}: cannot read the file ({error.strerror or error})") from None
    except tomllib.TOMLDecodeError as error:
        raise ValueError(f"{path}: not valid TOML ({error})") from None
    unknown = sorted(set(document) - {table})
    if table not in document or unknown:
        raise ValueError(
            f"{path}: expected one [{table}] table, got tables {sorted(document)}"
            + (f" (unknown: {unknown})" if unknown else "")
        )
    values = document[table]
    if not isinstance(values, dict):
        raise ValueError(f"{path}: [{table}] must be a table, got {shown(values)}")
    return values


def vehicle_from_table(values: Mapping[str, Any], source: str = "vehicle") -> AnyVehicle:
    """Build a vehicle from the fields of a ``[vehicle]`` table (see the module doc).

    Parameters
    ----------
    values : mapping
        ``model`` and/or ``preset``, then fields of :class:`Vehicle` or :class:`Vehicle6DOF`.
    source : str
        Where the values come from, for error messages (a file name).
    """
    fields = dict(values)
    preset_name = fields.pop("preset", None)
    model_name = fields.pop("model", None)
    base: AnyVehicle | None = None
    if preset_name is not None:
        if preset_name not in VEHICLE_PRESETS:
            raise ValueError(
                f"{source}: preset must be one of {list(VEHICLE_PRESETS)}, got {shown(preset_name)}"
            )
        base = VEHICLE_PRESETS[preset_name]()
    if model_name is not None and model_name not in _MODELS:
        raise ValueError(f"{source}: model must be one of {list(_MODELS)}, got {shown(model_name)}")
    if base is not None and model_name is not None and not isinstance(base, _MODELS[model_name]):
        raise ValueError(f"{source}: preset {preset_name!r} is not a {model_name!r} model")
    if base is None and model_name is None:
        raise ValueError(f"{source}: give model = 'planar' | '6dof' or a preset from {list(VEHICLE_PRESETS)}")
    cls = type(base) if base is not None else _MODELS[str(model_name)]
    allowed = {item.name for item in dataclasses.fields(cls) if item.init and item.name != "thrusters"}
    unknown = sorted(set(fields) - allowed)
    if unknown:
        raise ValueError(
            f"{source}: unknown vehicle field(s) {unknown}; {cls.__name__} has {sorted(allowed)}"
        )
    converted: dict[str, Any] = {
        key: tuple(value) if isinstance(value, list) else value for key, value in fields.items()
    }
    try:
        return dataclasses.replace(base, **converted) if base is not None else cls(**converted)
    except TypeError as error:  # a required field is missing
        raise ValueError(f"{source}: {error}") from None
    except ValueError as error:
        raise ValueError(f"{source}: {error}") from None


def vehicle_from_spec(spec: str | Path) -> AnyVehicle:
    """Build a vehicle from a preset name (:data:`VEHICLE_PRESETS`) or a TOML file (module doc).

    Raises
    ------
    ValueError
        Unknown name, unreadable file, or a bad field (the message names the file and field).
    """
    text = str(spec)
    if text in VEHICLE_PRESETS:
        return VEHICLE_PRESETS[text]()
    file, _, class_name = text.rpartition(":")
    if file.lower().endswith(".py") and class_name:
        return vehicle_from_class(Path(file), class_name)
    path = Path(text)
    if path.suffix.lower() != ".toml" or not path.is_file():
        raise ValueError(
            f"vehicle must be one of {list(VEHICLE_PRESETS)}, an existing .toml file or "
            f"FILE.py:CLASS, got {text!r}"
        )
    return vehicle_from_table(_read_table(path, "vehicle"), str(path))


def vehicle_from_class(path: Path, class_name: str) -> Any:
    """Build a user's vehicle: ``class_name()`` of the Python file ``path`` (``FILE.py:CLASS``).

    The file is run as a module of its own (its ``if __name__ == "__main__"`` block is not);
    the class is called without arguments and its product checked against the vehicle
    protocol (:func:`uuv_ocp.model.base.check_vehicle`).

    Raises
    ------
    ValueError
        No such file, an error while running it, no such class, or not a vehicle.
    """
    if not path.is_file():
        raise ValueError(f"vehicle file {str(path)!r} does not exist (FILE.py:CLASS)")
    # a module name of its own per file, so that two files with one stem do not collide
    module_name = "uuv_ocp_user_vehicle_" + hashlib.sha256(str(path.resolve()).encode()).hexdigest()[:16]
    module_spec = importlib.util.spec_from_file_location(module_name, path)
    if module_spec is None or module_spec.loader is None:
        raise ValueError(f"vehicle file {str(path)!r} cannot be loaded as Python")
    module = importlib.util.module_from_spec(module_spec)
    # registered as a module, as an import does: dataclasses and pickling (campaign workers)
    # look the class's module up in sys.modules
    sys.modules[module_name] = module
    try:
        module_spec.loader.exec_module(module)
    except BaseException as error:  # the user's code: its error, named, as a bad --vehicle
        del sys.modules[module_name]
        reraise_interrupt(error)  # Ctrl-C (CasADi reports it as a RuntimeError) stays one
        if not isinstance(error, Exception):
            raise
        raise ValueError(f"vehicle file {str(path)!r} raised {type(error).__name__}: {error}") from error
    factory = getattr(module, class_name, None)
    if not callable(factory):
        found = sorted(name for name, value in vars(module).items() if isinstance(value, type))
        raise ValueError(f"vehicle file {str(path)!r} has no class {class_name!r}; its classes: {found}")
    try:
        with BUILD_LOCK:  # a vehicle may build CasADi Functions as it is made (uuv_ocp._concurrency)
            vehicle = factory()
    except Exception as error:
        reraise_interrupt(error)
        raise ValueError(f"{class_name}() of {str(path)!r} raised {type(error).__name__}: {error}") from error
    return check_vehicle(f"vehicle {class_name} of {path}", vehicle)


def _waypoints_csv(path: Path) -> np.ndarray:
    try:
        points = np.loadtxt(path, delimiter=",", comments="#", ndmin=2)
    except OSError as error:
        raise ValueError(f"{path}: cannot read the file ({error.strerror or error})") from None
    except ValueError as error:
        raise ValueError(f"{path}: expected rows 'x, y[, z]' of numbers (m): {error}") from None
    if points.shape[1] not in (2, 3) or points.shape[0] < 2:
        raise ValueError(
            f"{path}: expected >= 2 rows of 'x, y[, z]' (m), got an array of shape {points.shape}"
        )
    return points


def reference_from_table(values: Mapping[str, Any], source: str = "reference") -> Reference:
    """Build a reference from the fields of a ``[reference]`` table (see the module doc)."""
    fields = dict(values)
    kind = fields.pop("kind", "waypoints")
    if kind not in REFERENCE_KINDS:
        raise ValueError(f"{source}: kind must be one of {list(REFERENCE_KINDS)}, got {shown(kind)}")
    constructor: Callable[..., Reference] = getattr(Reference, kind)
    try:
        return constructor(**fields)
    except TypeError as error:  # unknown or missing keyword
        raise ValueError(f"{source}: bad fields for a {kind} reference: {error}") from None
    except ValueError as error:
        raise ValueError(f"{source}: {error}") from None


def lift_to_depth(reference: Reference, depth: float = DEFAULT_DEPTH) -> Reference:
    """Fly the planar ``reference`` at constant ``depth`` (m, z down): a spatial reference."""
    if reference.spatial:
        return reference
    if not math.isfinite(depth):
        raise ValueError(f"depth must be a finite number (m), got {depth!r}")
    return dataclasses.replace(reference, path_z=lambda t: 0.0 * t + depth)


def reference_from_spec(
    spec: str | Sequence[str], *, spatial: bool = False, depth: float = DEFAULT_DEPTH
) -> Reference:
    """Build a reference from a spec (``s1``, ``waypoints FILE``, ``hold X,Y,PSI``, ...; module doc).

    Parameters
    ----------
    spec : str or sequence of str
        The words of the spec (``"waypoints survey.csv"`` or ``["waypoints", "survey.csv"]``).
    spatial : bool
        Whether a 6-DOF vehicle flies it: a planar paper reference is then lifted to ``depth``.
    depth : float
        Depth (m, z down) of a lifted planar reference.
    """
    words = spec.split() if isinstance(spec, str) else [str(word) for word in spec]
    usage = (
        f"reference must be one of {list(PAPER_REFERENCES)}, 'waypoints FILE', 'lawnmower FILE', "
        "'hold X,Y,PSI' or FILE.toml"
    )
    if not words:
        raise ValueError(f"{usage}, got nothing")
    head, rest = words[0], words[1:]
    if head in PAPER_REFERENCES and not rest:
        reference = Reference.paper(head)
    elif head == "hold" and len(rest) == 1:
        try:
            pose = [float(value) for value in rest[0].split(",")]
        except ValueError:
            raise ValueError(f"hold takes X,Y,PSI or X,Y,Z,PSI (m, rad), got {rest[0]!r}") from None
        reference = Reference.hold(pose)
    elif head in ("waypoints", "lawnmower") and len(rest) == 1:
        path = Path(rest[0])
        if head == "waypoints" and path.suffix.lower() != ".toml":
            points = _waypoints_csv(path)
            reference = Reference.waypoints(points, CSV_SPEED, CSV_TURN_RADIUS, name=path.stem)
        else:
            values = {"kind": head, **_read_table(path, "reference")} if path.is_file() else None
            if values is None:
                raise ValueError(f"{head}: no such file {str(path)!r}")
            if values["kind"] != head:
                raise ValueError(f"{path}: kind = {values['kind']!r}, but the spec says {head!r}")
            reference = reference_from_table(values, str(path))
    elif len(words) == 1 and head.lower().endswith(".toml") and Path(head).is_file():
        reference = reference_from_table(_read_table(Path(head), "reference"), head)
    else:
        raise ValueError(f"{usage}, got {' '.join(words)!r}")
    return lift_to_depth(reference, depth) if spatial else reference


def split_reference_specs(words: Sequence[str]) -> list[list[str]]:
    """Group command-line words into reference specs: ``s1 waypoints a.csv s2`` -> three specs.

    ``waypoints``, ``lawnmower`` and ``hold`` take the word after them; every other word is a
    spec of its own (a paper name or a TOML file).
    """
    groups: list[list[str]] = []
    index = 0
    while index < len(words):
        word = str(words[index])
        width = 2 if word in _TAKES_ARGUMENT else 1
        groups.append([str(w) for w in words[index : index + width]])
        index += width
    return groups


_TAKES_ARGUMENT = ("waypoints", "lawnmower", "hold")
