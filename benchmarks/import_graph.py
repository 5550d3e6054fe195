"""The import graph of ``src/uuv_ocp``, counting imports inside functions: cycles and deferred imports.

Every module is parsed with :mod:`ast` (nothing is imported), and every ``import`` of a ``uuv_ocp``
module becomes an edge, wherever it stands: at module level, inside a function or method (a
*deferred* import), or under ``if TYPE_CHECKING:`` (a *typing* import, listed but not an edge:
it never runs). ``from uuv_ocp.x import y`` is an edge to ``uuv_ocp.x.y`` when ``y`` is a
submodule, else to ``uuv_ocp.x``; relative imports are resolved. Importing ``uuv_ocp.a.b`` also
runs the package ``uuv_ocp.a``'s ``__init__``; that implicit parent edge is not counted (every
module would otherwise sit in one loop through ``uuv_ocp/__init__.py``'s re-exports).

A deferred import that closes a cycle hides it from Python but not from this graph: the strongly
connected components (Tarjan) of the graph with deferred edges are the loops of the design.
A *dynamic* import of a package module (``importlib.import_module("uuv_ocp...")`` or
``__import__``, e.g. in a module ``__getattr__``) cannot be resolved statically; such calls are
listed so that none hides a loop.

Run: ``python -m benchmarks.import_graph [--check] [--verbose] [--root src/uuv_ocp]``.
``--check`` exits 1 when a cycle or a dynamic import of a package module exists.
"""

from __future__ import annotations

import argparse
import ast
import sys
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1] / "src" / "uuv_ocp"
PACKAGE = "uuv_ocp"
DYNAMIC = "<dynamic uuv_ocp import>"


@dataclass(frozen=True)
class Import:
    """One import statement's target inside the package."""

    source: str  # importing module, dotted
    target: str  # imported uuv_ocp module, dotted
    line: int
    where: str  # "module", "function" or "typing"


def module_names(root: Path) -> dict[str, Path]:
    """Map every module under ``root`` to its dotted name (packages by their ``__init__``)."""
    names = {}
    for path in sorted(root.rglob("*.py")):
        parts = list(path.relative_to(root.parent).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts.pop()
        names[".".join(parts)] = path
    return names


def _is_type_checking(test: ast.expr) -> bool:
    return (isinstance(test, ast.Name) and test.id == "TYPE_CHECKING") or (
        isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING"
    )


def _walk(node: ast.AST, where: str) -> Iterator[tuple[ast.Import | ast.ImportFrom, str]]:
    """Yield every import under ``node`` with where it stands (the innermost function wins)."""
    for child in ast.iter_child_nodes(node):
        if isinstance(child, ast.Import | ast.ImportFrom):
            yield child, where
        elif isinstance(child, ast.FunctionDef | ast.AsyncFunctionDef | ast.Lambda):
            yield from _walk(child, "function")
        elif isinstance(child, ast.If) and _is_type_checking(child.test) and where == "module":
            for statement in child.body:
                yield from _walk(ast.Module(body=[statement], type_ignores=[]), "typing")
            for statement in child.orelse:
                yield from _walk(ast.Module(body=[statement], type_ignores=[]), where)
        else:
            yield from _walk(child, where)


def _resolve(module: str, is_package: bool, node: ast.ImportFrom) -> str:
    """Return the absolute module a ``from ... import`` names (relative levels resolved)."""
    if not node.level:
        return node.module or ""
    base = module.split(".")
    if not is_package:
        base = base[:-1]
    base = base[: len(base) - (node.level - 1)]
    return ".".join([*base, node.module] if node.module else base)


def _dynamic(tree: ast.AST) -> Iterator[int]:
    """Lines of ``import_module(...)`` / ``__import__(...)`` calls whose name starts with the package."""
    for node in ast.walk(tree):
        if not (isinstance(node, ast.Call) and node.args):
            continue
        function = node.func
        name = function.attr if isinstance(function, ast.Attribute) else getattr(function, "id", "")
        if name not in ("import_module", "__import__"):
            continue
        first = node.args[0]
        if isinstance(first, ast.JoinedStr) and first.values:
            first = first.values[0]
        if isinstance(first, ast.Constant) and str(first.value).startswith(PACKAGE):
            yield node.lineno


def imports(root: Path = ROOT) -> tuple[list[Import], list[tuple[str, int, str]]]:
    """Every ``uuv_ocp`` import inside the package, and every deferred import of any module.

    Returns
    -------
    internal
        The imports of package modules (edges), with where they stand.
    deferred
        ``(module, line, imported name)`` of every import inside a function, of any package
        (``matplotlib``, ``dask``, ... included), for the count; dynamic imports of package
        modules (:func:`_dynamic`) appear here with the name ``"<dynamic uuv_ocp import>"``.
    """
    names = module_names(root)
    internal: list[Import] = []
    deferred: list[tuple[str, int, str]] = []
    for module, path in names.items():
        tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
        is_package = path.name == "__init__.py"
        deferred.extend((module, line, DYNAMIC) for line in _dynamic(tree))
        for node, where in _walk(tree, "module"):
            if isinstance(node, ast.Import):
                targets = [alias.name for alias in node.names]
            else:
                base = _resolve(module, is_package, node)
                # ``from pkg import name``: an edge to the submodule when it is one, else to pkg.
                targets = [
                    f"{base}.{alias.name}" if f"{base}.{alias.name}" in names else base
                    for alias in node.names
                ]
            if where == "function":
                deferred.extend((module, node.lineno, target) for target in dict.fromkeys(targets))
            for target in dict.fromkeys(targets):
                if target == PACKAGE or target.startswith(PACKAGE + "."):
                    # ``import uuv_ocp.a.b`` names the deepest known module of the dotted path.
                    while target not in names and "." in target:
                        target = target.rsplit(".", 1)[0]
                    if target != module:
                        internal.append(Import(module, target, node.lineno, where))
    return internal, deferred


def strongly_connected(nodes: list[str], edges: dict[str, set[str]]) -> list[list[str]]:
    """Tarjan's strongly connected components with more than one module (or a self-loop)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    components: list[list[str]] = []
    counter = 0

    def visit(start: str) -> None:
        # Iterative, so a deep graph cannot hit the recursion limit.
        nonlocal counter
        work = [(start, iter(sorted(edges.get(start, ()))))]
        index[start] = low[start] = counter
        counter += 1
        stack.append(start)
        on_stack.add(start)
        while work:
            node, children = work[-1]
            for child in children:
                if child not in index:
                    index[child] = low[child] = counter
                    counter += 1
                    stack.append(child)
                    on_stack.add(child)
                    work.append((child, iter(sorted(edges.get(child, ())))))
                    break
                if child in on_stack:
                    low[node] = min(low[node], index[child])
            else:
                work.pop()
                if work:
                    parent = work[-1][0]
                    low[parent] = min(low[parent], low[node])
                if low[node] == index[node]:
                    component = []
                    while True:
                        member = stack.pop()
                        on_stack.discard(member)
                        component.append(member)
                        if member == node:
                            break
                    if len(component) > 1 or node in edges.get(node, ()):
                        components.append(sorted(component))

    for node in nodes:
        if node not in index:
            visit(node)
    return sorted(components, key=lambda c: (-len(c), c))


@dataclass(frozen=True)
class Graph:
    """The package's import graph and what the design checks on it."""

    modules: list[str]
    internal: list[Import]
    deferred: list[tuple[str, int, str]]
    cycles: list[list[str]]

    @property
    def deferred_internal(self) -> list[Import]:
        """Imports of package modules inside functions."""
        return [item for item in self.internal if item.where == "function"]

    @property
    def dynamic(self) -> list[tuple[str, int]]:
        """``(module, line)`` of every ``import_module``/``__import__`` of a package module."""
        return [(module, line) for module, line, target in self.deferred if target == DYNAMIC]


def graph(root: Path = ROOT) -> Graph:
    """Parse the package under ``root`` and find its cycles (deferred imports counted as edges)."""
    internal, deferred = imports(root)
    modules = sorted(module_names(root))
    edges: dict[str, set[str]] = {}
    for item in internal:
        if item.where != "typing":
            edges.setdefault(item.source, set()).add(item.target)
    return Graph(modules, internal, deferred, strongly_connected(modules, edges))


def main(argv: list[str] | None = None) -> int:
    """Print the counts and the cycles; with ``--check``, exit 1 when a cycle exists."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--root", type=Path, default=ROOT, help="the package directory")
    parser.add_argument("--check", action="store_true", help="exit 1 on a cycle or a dynamic import")
    parser.add_argument("--verbose", action="store_true", help="list every deferred import")
    args = parser.parse_args(argv)
    result = graph(args.root)
    print(f"modules: {len(result.modules)}")
    print(f"imports inside functions (any package): {len(result.deferred)}")
    print(f"imports inside functions of uuv_ocp modules: {len(result.deferred_internal)}")
    print(f"dynamic imports of uuv_ocp modules (importlib): {len(result.dynamic)}")
    if args.verbose:
        for module, line, target in result.deferred:
            print(f"  {module}:{line} -> {target}")
    print(f"strongly connected components (cycles): {len(result.cycles)}")
    for component in result.cycles:
        print(f"  {len(component)} modules: {', '.join(component)}")
    return 1 if args.check and (result.cycles or result.dynamic) else 0


if __name__ == "__main__":
    sys.exit(main())
