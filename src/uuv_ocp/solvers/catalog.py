"""The declared options of registered solvers, by name: the lookup and the docs' tables.

A layer above the registry (:mod:`uuv_ocp.solvers`), which imports every backend, which imports
:mod:`uuv_ocp.solvers.options`: reading a declaration by name therefore lives here, not in
``options``, so that no module imports the registry from below it.
"""

from __future__ import annotations

from collections.abc import Sequence

from uuv_ocp.solvers import REGISTRY
from uuv_ocp.solvers.options import Option, default_cell

__all__ = ["declared_options", "options_table"]


def declared_options(name: str) -> tuple[Option, ...]:
    """Return the declaration of the backend registered as ``name`` (its factory's ``OPTIONS``).

    Raises
    ------
    ValueError
        Unknown solver name (the registry's message), or a backend that declares no options.
    """
    resolved = REGISTRY.resolve(name)
    options = getattr(REGISTRY.factory(resolved), "OPTIONS", None)
    if options is None:
        raise ValueError(
            f"solver {resolved!r} declares no options: give its factory an OPTIONS tuple of "
            "uuv_ocp.solvers.options.Option (see that module's docstring)"
        )
    return tuple(options)


def options_table(names: str | Sequence[str]) -> str:
    """Markdown table of the options of one backend, or of several that share one declaration.

    One row per declared option, in declaration order.  With several names (e.g. the four
    swarms) their declarations must list the same options in the same order; a default that
    differs between them reads "per solver" and a second table gives it for each name (one
    row per name, one column per such option).
    """
    group = [names] if isinstance(names, str) else list(names)
    if not group:
        raise ValueError("options_table needs at least one solver name, got none")
    declarations = [declared_options(name) for name in group]
    first = declarations[0]
    for name, options in zip(group[1:], declarations[1:], strict=True):
        if [o.name for o in options] != [o.name for o in first]:
            raise ValueError(
                f"options_table: {group[0]!r} and {name!r} declare different options "
                f"({[o.name for o in first]} vs {[o.name for o in options]}); render them separately"
            )
    header = ["option", "default", "values", "unit", "description"]
    lines = [_row(header), _row(["---"] * len(header))]
    differing: list[int] = []
    for row, option in enumerate(first):
        shown = {default_cell(options[row]) for options in declarations}
        if len(shown) > 1:
            differing.append(row)
        default = "per solver, see below" if len(shown) > 1 else default_cell(option)
        lines.append(_row([f"`{option.name}`", default, option.kind, option.unit, option.description]))
    if differing:
        lines += ["", _row(["solver", *(f"`{first[row].name}`" for row in differing)])]
        lines.append(_row(["---"] * (len(differing) + 1)))
        for name, options in zip(group, declarations, strict=True):
            lines.append(_row([f"`{name}`", *(default_cell(options[row]) for row in differing)]))
    return "\n".join(lines) + "\n"


def _cell(text: str) -> str:
    """Return a table cell: ``|`` escaped, empty as a dash."""
    return text.replace("|", "\\|") if text else "—"


def _row(cells: Sequence[str]) -> str:
    return "| " + " | ".join(_cell(cell) for cell in cells) + " |"
