"""The tests mirror the package: ``src/uuv_ocp/<pkg>/<module>.py`` <-> ``tests/<pkg>/test_<module>.py``.

A module without its mirror must say here where it is tested and by which name that file uses
it, so a module added without tests, a mirror renamed away or an entry left stale fails.
Cross-cutting tests (the public API, bad inputs, threads, docs, examples, imports) live in
``tests/system/``.
"""

from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
PACKAGE = ROOT / "src" / "uuv_ocp"
TESTS = ROOT / "tests"

#: module (relative to src/uuv_ocp) -> (test file that tests it, a name that file must use)
TESTED_ELSEWHERE = {
    "_validation.py": ("system/test_bad_inputs.py", "ValueError"),
    "_version.py": ("native/test_compile_security.py", "__version__"),
    "control/disturbances.py": ("control/test_simulation.py", "GaussMarkov"),
    "judge.py": ("solvers/test_swarm.py", "uuv_ocp.judge"),
    "model/damping.py": ("model/test_remus100.py", "steady_speed"),
    "native/runtime.py": ("native/test_compile.py", "runtime"),
    "optimize/benchmark_functions.py": ("optimize/test_optimisers.py", "benchmark_functions"),
    "optimize/gwo.py": ("optimize/test_optimisers.py", '"gwo"'),
    "optimize/igwo.py": ("optimize/test_optimisers.py", '"igwo"'),
    "optimize/pso.py": ("optimize/test_optimisers.py", '"pso"'),
    "optimize/ssa.py": ("optimize/test_optimisers.py", '"ssa"'),
    "optimize/schedules.py": ("optimize/test_optimisers.py", "convergence_factor"),
    "optimize/loop.py": ("optimize/test_extension.py", "uuv_ocp.optimize.loop"),
    "optimize/minimize.py": ("optimize/test_extension.py", "uo.minimize"),
    "solvers/catalog.py": ("solvers/test_options.py", "uuv_ocp.solvers.catalog"),
    "solvers/fatrop.py": ("solvers/test_nlp.py", '"fatrop"'),
    "solvers/ipopt.py": ("solvers/test_nlp.py", '"ipopt"'),
    "solvers/sqp.py": ("solvers/test_nlp.py", "uuv_ocp.solvers.sqp"),
    "solvers/hybrid.py": ("solvers/test_swarm.py", "+"),
    "solvers/multistart.py": ("test_obstacles.py", "multistart"),
    "solvers/rti_ocp.py": ("solvers/test_rti.py", "hpipm-ocp"),
    "studies/campaign_file.py": ("studies/test_campaign.py", "campaign_file"),
    "studies/compare.py": ("model/test_top_speed.py", "uuv_ocp.studies.compare"),
    "studies/paper_data.py": ("studies/test_reproduce.py", "paper_data"),
    "studies/paper_figures.py": ("studies/test_reproduce.py", "figure"),
    "studies/records.py": ("studies/test_campaign_processes.py", "records"),
    "studies/report.py": ("studies/test_reproduce.py", "report"),
    "studies/reproduction.py": ("studies/test_reproduce.py", "reproduce"),
    "transcription/condensed.py": ("solvers/test_swarm.py", "uuv_ocp.transcription.condensed"),
    "transcription/multiple_shooting.py": ("transcription/test_collocation.py", "multiple"),
}


def modules() -> list[str]:
    """Every module of the package except the packages' ``__init__`` files."""
    return sorted(
        str(path.relative_to(PACKAGE)) for path in PACKAGE.rglob("*.py") if path.name != "__init__.py"
    )


def mirror(module: str) -> Path:
    """``tests/<package>/test_<module>.py`` (a leading underscore of a private module dropped)."""
    path = Path(module)
    return TESTS / path.parent / f"test_{path.stem.lstrip('_')}.py"


@pytest.mark.parametrize("module", modules())
def test_every_module_has_its_mirror_or_says_where_it_is_tested(module):
    if mirror(module).is_file():
        assert module not in TESTED_ELSEWHERE, f"{module} has its mirror: drop its TESTED_ELSEWHERE entry"
        return
    assert module in TESTED_ELSEWHERE, f"{module}: no {mirror(module).relative_to(ROOT)} and no entry here"
    test_file, name = TESTED_ELSEWHERE[module]
    text = (TESTS / test_file).read_text(encoding="utf-8")
    assert name in text, f"{module}: tests/{test_file} does not use {name!r}"


def test_every_entry_names_a_module_that_exists():
    assert sorted(set(TESTED_ELSEWHERE) - set(modules())) == []


def test_test_folders_are_package_folders():
    # tests/<package>/ mirrors src/uuv_ocp/<package>/ (plus system/ for what crosses packages)
    folders = {path.name for path in TESTS.iterdir() if path.is_dir() and (path / "__init__.py").is_file()}
    packages = {path.name for path in PACKAGE.iterdir() if path.is_dir() and any(path.glob("*.py"))}
    assert folders - {"system"} <= packages
