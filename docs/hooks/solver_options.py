"""mkdocs hook: ``<!-- solver-options: NAME [NAME ...] -->`` becomes the options table of those solvers.

The table is :func:`uuv_ocp.solvers.catalog.options_table` of the names, rendered from the
backends' declarations in the code, so the documented options and defaults cannot drift from
the ones the constructors use.  Several names (the four swarms) share one table.  An unknown
name, or a backend that declares no options, fails the build.  Registered in mkdocs.yml under
``hooks:``.
"""

from __future__ import annotations

import re
from typing import Any

from mkdocs.exceptions import PluginError

MARKER = re.compile(r"<!--\s*solver-options:\s*(?P<names>[^>]*?)\s*-->")


def render(markdown: str) -> str:
    """Return ``markdown`` with every solver-options marker replaced by its table."""
    from uuv_ocp.solvers.catalog import options_table

    def table(match: re.Match[str]) -> str:
        names = match["names"].split()
        try:
            return options_table(names[0] if len(names) == 1 else names)
        except ValueError as error:
            raise PluginError(f"{match[0]}: {error}") from error

    return MARKER.sub(table, markdown)


def on_page_markdown(markdown: str, page: Any, config: Any, files: Any) -> str:
    """Mkdocs event: render the markers of every page before it is converted to HTML."""
    return render(markdown)
