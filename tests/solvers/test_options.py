"""Declared solver options (uuv_ocp.solvers.options) against what the constructors really do.

For every registered solver name: each declared option is accepted with its declared default,
an undeclared one is rejected by name, the built backend holds the declared default, the options
dataclass the generic parser reads is the declaration, and the table of docs/solvers.md has one
row per declared option whose default, read back as Python, is the value the backend holds.
"""

import ast
import dataclasses
import importlib.util
import os
import re
from pathlib import Path

import pytest

import uuv_ocp as uo
from uuv_ocp.solvers import REGISTRY
from uuv_ocp.solvers.catalog import declared_options, options_table
from uuv_ocp.solvers.hybrid import HYBRID_OPTIONS
from uuv_ocp.solvers.multistart import MULTISTART_OPTIONS
from uuv_ocp.solvers.options import AUTO, Option, declaration, option_defaults, parse_options

ROOT = Path(__file__).resolve().parents[2]
NAMES = uo.available_solvers()
BASE = [name for name in NAMES if REGISTRY.kind(name) in ("exact", "swarm")]
UNKNOWN = "not_an_option_xyz"


@pytest.fixture(scope="module")
def tiny():
    """RexROV on s2 with a three-step horizon: every backend builds in well under a second."""
    return uo.TrackingProblem(uo.Vehicle.rexrov(), uo.Reference.paper("s2"), horizon=3)


@pytest.fixture(autouse=True)
def _virtual_machine(monkeypatch):
    # the swarms' compiled="auto" then means the virtual machine (no 20 s build per problem)
    monkeypatch.setenv("UUV_OCP_COMPILED", "0")


def build(problem, name, options=None):
    return REGISTRY.factory(name)(problem, options)


def expected_held(option: Option, name: str):
    """Return the value a backend built without options holds for ``option`` (independently).

    Literal defaults are held as declared; the three worked out when the backend is built are
    computed here from the rule their ``meaning`` states.
    """
    if REGISTRY.kind(name) == "swarm" and option.name == "compiled":
        assert option.default == "auto"
        return False  # "auto" with UUV_OCP_COMPILED=0
    if name == "sqp-rti" and option.name == "qpsol":
        assert option.default == "auto"
        return "hpipm"  # "auto" with UUV_OCP_COMPILED=0: CasADi's interface, no C build
    if option.default is AUTO:
        if option.name == "rng_thread":
            return len(os.sched_getaffinity(0)) >= 2
        if option.name == "candidate_distance":
            return 0.5  # candidate_metric "states", the declared default metric
        if option.name == "qpsol_options":
            return {}  # sqp-rti's default mode "rti": HPIPM's own tolerances
        raise AssertionError(f"{name}: no independent rule for the auto default of {option.name!r}")
    return option.default


def assert_holds_defaults(backend, name: str) -> None:
    """Every declared default is the value ``backend`` (built without options) holds."""
    kind = REGISTRY.kind(name)
    for option in declared_options(name):
        if kind == "hybrid" and option.name in ("swarm", "exact", "candidate_distance"):
            continue  # passed on to the halves: checked on them below
        if kind == "multistart" and option.name == "exact":
            continue  # passed on to the exact backend: checked on it below
        held = getattr(backend, option.name)
        assert held == expected_held(option, name), (name, option.name, held)
    if kind == "hybrid":
        first, _, second = name.partition("+")
        assert_holds_defaults(backend.first, first)
        assert_holds_defaults(backend.second, second)
        # candidate_distance None: the swarm's own default
        assert backend.first.candidate_distance == 0.5
    elif kind == "multistart":
        assert_holds_defaults(backend.exact, name.removeprefix("multistart-"))


@pytest.mark.parametrize("name", BASE)
def test_every_registered_backend_declares_its_options(name):
    """A backend registered without an OPTIONS declaration fails here."""
    options = declared_options(name)
    assert options and all(isinstance(option, Option) for option in options)
    names = [option.name for option in options]
    assert len(set(names)) == len(names)
    factory = REGISTRY.factory(name)
    if hasattr(factory, "option_names"):  # the tuple the unknown-option error lists
        assert set(factory.option_names) == set(names), (
            f"{name}: option_names differ from its OPTIONS declaration by "
            f"{sorted(set(factory.option_names) ^ set(names))}; declare OPTIONS and derive "
            "option_names from it (see uuv_ocp.solvers.options)"
        )


@pytest.mark.parametrize("name", NAMES)
def test_declared_defaults_are_accepted(tiny, name):
    options = option_defaults(declared_options(name))
    backend = build(tiny, name, options)
    assert backend.name == name


@pytest.mark.parametrize("name", NAMES)
def test_undeclared_option_is_rejected_by_name(tiny, name):
    with pytest.raises(ValueError, match=UNKNOWN):
        build(tiny, name, {UNKNOWN: 1})


@pytest.mark.parametrize("name", NAMES)
def test_declared_default_is_the_value_the_backend_holds(tiny, name):
    assert_holds_defaults(build(tiny, name), name)


# options as frozen dataclasses, read by the one generic parser (uuv_ocp.solvers.options.parse_options)
def _declares_options_class(name: str) -> bool:
    """Whether the factory of ``name`` declares an Options dataclass of its own (not inherited)."""
    factory = REGISTRY.factory(name)
    return "Options" in (vars(factory) if isinstance(factory, type) else factory.__dict__)


PARSED = [name for name in ["igwo+ipopt", "multistart-ipopt", *BASE] if _declares_options_class(name)]


def test_every_backend_parses_an_options_dataclass():
    """A new backend declares an Options dataclass: what it does not declare is refused."""
    assert set(BASE) - {name for name in PARSED} == set()


@pytest.mark.parametrize("name", PARSED)
def test_the_options_dataclass_is_the_declaration_the_docs_render(name):
    factory = REGISTRY.factory(name)
    assert dataclasses.is_dataclass(factory.Options) and factory.Options.__dataclass_params__.frozen
    assert declaration(factory.Options) == declared_options(name)
    parsed = parse_options(factory.Options, None, name)
    assert dataclasses.asdict(parsed) == option_defaults(declared_options(name))


@pytest.mark.parametrize("name", PARSED)
def test_the_generic_parser_refuses_undeclared_names_and_bad_values(name):
    factory = REGISTRY.factory(name)
    with pytest.raises(ValueError, match=rf"unknown options for solver '{re.escape(name)}'.*{UNKNOWN}"):
        parse_options(factory.Options, {UNKNOWN: 1}, name)
    with pytest.raises(ValueError, match="must be a dict or None"):
        parse_options(factory.Options, "fast", name)
    for field in dataclasses.fields(factory.Options):
        assert field.metadata["option"].check is not None, (name, field.name)
        with pytest.raises(ValueError, match=re.escape(f"options['{field.name}']")):
            parse_options(factory.Options, {field.name: "~not a value~"}, name)


def test_parsed_options_are_frozen():
    parsed = parse_options(REGISTRY.factory("ipopt").Options, {"max_iter": 5}, "ipopt")
    assert parsed.max_iter == 5
    with pytest.raises(dataclasses.FrozenInstanceError):
        parsed.max_iter = 6


def _tables(markdown: str) -> list[list[list[str]]]:
    r"""Return the Markdown tables of ``markdown``: rows of cells (``\|`` unescaped), header included."""
    tables, current = [], []
    for line in [*markdown.splitlines(), ""]:
        if line.startswith("|"):
            cells = [c.strip().replace("\\|", "|") for c in re.split(r"(?<!\\)\|", line.strip())[1:-1]]
            if not all(set(c) <= {"-", " "} for c in cells):
                current.append(cells)
        elif current:
            tables.append(current)
            current = []
    return tables


def _value(cell: str):
    """Return the Python value of a rendered default cell (``AUTO`` for a worked-out default)."""
    if cell.startswith("auto"):
        return AUTO
    match = re.match(r"`([^`]*)`", cell)
    assert match, cell
    return ast.literal_eval(match[1])


@pytest.mark.parametrize("group", [("ipopt",), ("fatrop",), ("sqp",), ("igwo", "gwo", "ssa", "pso")])
def test_table_has_one_row_per_option_with_the_default_the_backend_holds(tiny, group):
    tables = _tables(options_table(group[0] if len(group) == 1 else list(group)))
    header, *rows = tables[0]
    assert header[:2] == ["option", "default"]
    for name in group:
        options = declared_options(name)
        assert [row[0] for row in rows] == [f"`{option.name}`" for option in options]
        per_solver = {}
        if len(tables) > 1:  # defaults that differ between the group's solvers
            (_, *columns), *lines = tables[1]
            line = next(line for line in lines if line[0] == f"`{name}`")
            per_solver = dict(zip(columns, line[1:], strict=True))
        backend = build(tiny, name)
        for option, row in zip(options, rows, strict=True):
            cell = per_solver.get(row[0], row[1])
            shown = _value(cell)
            if shown is AUTO or (isinstance(option.default, str) and option.default == "auto"):
                assert getattr(backend, option.name) == expected_held(option, name)
            else:
                assert shown == getattr(backend, option.name), (name, option.name, cell)


@pytest.mark.parametrize(
    ("name", "options"), [("igwo+ipopt", HYBRID_OPTIONS), ("multistart-sqp", MULTISTART_OPTIONS)]
)
def test_composite_tables_list_their_declaration(name, options):
    (_, *rows), *_ = _tables(options_table(name))
    assert [row[0] for row in rows] == [f"`{option.name}`" for option in options]
    assert [_value(row[1]) for row in rows] == [option.default for option in options]


def test_swarm_tables_read_population_and_iterations_from_the_algorithms():
    from uuv_ocp.optimize import ALGORITHMS
    from uuv_ocp.solvers import REGISTRY

    # the swarm backends built from the algorithms (mppi's backend is MppiSolver: samples, not population)
    swarms = {m: a for m, a in ALGORITHMS.items() if REGISTRY.factory(m).__name__ == f"{m}_factory"}
    assert set(ALGORITHMS) - set(swarms) == {"mppi"}
    for method, algorithm in swarms.items():
        defaults = option_defaults(declared_options(method))
        assert (defaults["population"], defaults["iterations"]) == (
            algorithm.default_population,
            algorithm.default_iterations,
        )
    populations = {option_defaults(declared_options(m))["population"] for m in swarms}
    assert len(populations) > 1  # so the shared table needs its per-solver part


def test_a_backend_without_declaration_is_reported():
    class Undeclared:
        name = "undeclared-for-options-test"

        def __init__(self, problem, options=None):
            self.problem = problem

        def solve(self, p, warm_start=None, rng=None):
            raise AssertionError("never called")

    REGISTRY.register(Undeclared.name, Undeclared, kind="exact", overwrite=True)
    try:
        with pytest.raises(ValueError, match="declares no options"):
            declared_options(Undeclared.name)
        with pytest.raises(ValueError, match="declares no options"):
            options_table(Undeclared.name)
    finally:
        REGISTRY._factories.pop(Undeclared.name, None)


def test_option_declarations_are_checked():
    with pytest.raises(ValueError, match="meaning"):
        Option("max_iter", None, "int >= 1 or `None`", "iteration limit")
    with pytest.raises(ValueError, match="identifier"):
        Option("Max Iter", 1, "int", "iteration limit")
    with pytest.raises(ValueError, match="one non-empty line"):
        Option("max_iter", 1, "int", "two\nlines")


def _hook():
    pytest.importorskip("mkdocs")
    path = ROOT / "docs" / "hooks" / "solver_options.py"
    spec = importlib.util.spec_from_file_location("solver_options_hook", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_docs_page_has_a_table_for_every_backend():
    hook = _hook()
    page = (ROOT / "docs" / "solvers.md").read_text()
    markers = [match["names"].split() for match in hook.MARKER.finditer(page)]
    covered = {name for names in markers for name in names}
    assert set(BASE) <= covered, f"no <!-- solver-options: ... --> marker for {sorted(set(BASE) - covered)}"
    assert {REGISTRY.kind(name) for name in covered} == {"exact", "swarm", "hybrid", "multistart"}
    rendered = hook.render(page)
    assert "solver-options:" not in rendered
    assert rendered.count("| `deadline` |") == len(markers)  # every backend takes a deadline


def test_hook_fails_on_an_unknown_solver():
    hook = _hook()  # skips the test where mkdocs (the `docs` extra) is not installed
    from mkdocs.exceptions import PluginError

    with pytest.raises(PluginError, match="newton"):
        hook.render("text\n\n<!-- solver-options: newton -->\n")
