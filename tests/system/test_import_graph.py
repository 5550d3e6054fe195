"""Layers point down: no import cycle in the package, counting imports inside functions.

The checker (``benchmarks/import_graph.py``) parses the package that is imported here, so
running this file with another checkout on ``PYTHONPATH`` checks that checkout.
"""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import pytest

import uuv_ocp as uo

PACKAGE_ROOT = Path(uo.__file__).resolve().parent
CHECKER = Path(__file__).resolve().parents[2] / "benchmarks" / "import_graph.py"


def _checker():
    spec = importlib.util.spec_from_file_location("import_graph_checker", CHECKER)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # dataclasses look their module up while being built
    spec.loader.exec_module(module)
    return module


import_graph = _checker()


def _package(tmp_path: Path, files: dict[str, str]) -> Path:
    """Write a throwaway package named ``uuv_ocp`` (the checker's package name) and return it."""
    root = tmp_path / "uuv_ocp"
    for name, text in {"__init__.py": "", **files}.items():
        path = root / name
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text)
    return root


def test_the_package_has_no_import_cycle():
    result = import_graph.graph(PACKAGE_ROOT)
    assert result.cycles == [], "import cycles (function-level imports counted): " + "; ".join(
        ", ".join(component) for component in result.cycles
    )


def test_no_module_imports_a_package_module_by_a_computed_name():
    # importlib.import_module("uuv_ocp...") (the old nlp.__getattr__ shim) escapes the graph
    assert import_graph.graph(PACKAGE_ROOT).dynamic == []


def test_nothing_in_the_package_imports_the_codegen_facade():
    users = [
        f"{item.source}:{item.line}"
        for item in import_graph.graph(PACKAGE_ROOT).internal
        if item.target == "uuv_ocp.codegen"
    ]
    assert users == []


def test_the_codegen_facade_keeps_its_names():
    from uuv_ocp import codegen
    from uuv_ocp.native import runtime
    from uuv_ocp.solvers import rti_export

    assert codegen.generate_c is uo.generate_c is rti_export.generate_c
    assert codegen.GeneratedCode is uo.GeneratedCode is runtime.GeneratedCode
    runtime_names = ("NativeIgwo", "compiled_build", "jit_directory", "default_cache_directory")
    for name in (*runtime_names, "hpipm_link_flags"):
        assert getattr(codegen, name) is getattr(runtime, name), name
    assert set(codegen.__all__) <= set(dir(codegen))


def test_a_cycle_hidden_in_a_function_is_found(tmp_path):
    root = _package(
        tmp_path,
        {
            "a.py": "from uuv_ocp.b import g\n",
            "b.py": "def g():\n    from uuv_ocp import a\n    return a\n",
            "c.py": "import uuv_ocp.a\n",
        },
    )
    result = import_graph.graph(root)
    assert result.cycles == [["uuv_ocp.a", "uuv_ocp.b"]]
    assert [(i.source, i.target) for i in result.deferred_internal] == [("uuv_ocp.b", "uuv_ocp.a")]
    assert import_graph.main(["--root", str(root), "--check"]) == 1
    assert import_graph.main(["--root", str(root)]) == 0


def test_a_dynamic_import_of_a_package_module_is_reported(tmp_path):
    root = _package(
        tmp_path,
        {
            "a.py": (
                "import importlib\n"
                "def __getattr__(name):\n"
                "    return importlib.import_module(f'uuv_ocp.{name}')\n"
                "def other():\n"
                "    return importlib.import_module('json')\n"
            ),
        },
    )
    result = import_graph.graph(root)
    assert result.dynamic == [("uuv_ocp.a", 3)]
    assert import_graph.main(["--root", str(root), "--check"]) == 1


def test_relative_submodule_and_typing_imports_are_resolved(tmp_path):
    root = _package(
        tmp_path,
        {
            "sub/__init__.py": "from . import leaf\n",
            "sub/leaf.py": "from ..top import VALUE\n",
            "sub/other.py": (
                "from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from uuv_ocp.sub import leaf\n"
            ),
            "top.py": "from uuv_ocp.sub import other\nVALUE = 1\n",
        },
    )
    result = import_graph.graph(root)
    edges = {(i.source, i.target, i.where) for i in result.internal}
    assert edges == {
        ("uuv_ocp.sub", "uuv_ocp.sub.leaf", "module"),
        ("uuv_ocp.sub.leaf", "uuv_ocp.top", "module"),
        ("uuv_ocp.sub.other", "uuv_ocp.sub.leaf", "typing"),
        ("uuv_ocp.top", "uuv_ocp.sub.other", "module"),
    }
    # sub.other -> sub.leaf -> top -> sub.other would be a loop, but the first edge never runs
    assert result.cycles == []


@pytest.mark.parametrize("statement", ["import uuv_ocp.a.b", "from uuv_ocp.a import b"])
def test_a_dotted_import_names_the_deepest_module(tmp_path, statement):
    root = _package(tmp_path, {"a/__init__.py": "", "a/b.py": "", "c.py": statement + "\n"})
    assert [(i.source, i.target) for i in import_graph.graph(root).internal] == [("uuv_ocp.c", "uuv_ocp.a.b")]
