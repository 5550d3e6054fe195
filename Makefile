# Two commands set up a fresh machine: `make demo` and `make test`.
PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed

.PHONY: demo test bench lint docs clean hpipm

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e ".[test]"
	touch $(STAMP)

# `make demo FRESH=1` recomputes the runs a previous demo saved in out/runs.
demo: $(STAMP)
	$(PY) -m uuv_ocp.cli demo $(if $(FRESH),--fresh)

# One BLAS thread: scipy's SLSQP (the slsqp backend) calls OpenBLAS on small matrices, where
# its threads only contend with the suite's own processes (docs/benchmarks.md, "SLSQP").
test: $(STAMP)
	OPENBLAS_NUM_THREADS=1 $(PY) -m pytest -q

# The benchmarks get a venv of their own: mealpy (the reference implementation they compare
# with) pins numpy<=1.26.0, which must not leak into the test environment.
BENCH_VENV := .venv-bench
BENCH_STAMP := $(BENCH_VENV)/.installed

$(BENCH_STAMP): pyproject.toml
	$(PYTHON) -m venv $(BENCH_VENV)
	$(BENCH_VENV)/bin/python -m pip install --quiet --upgrade pip
	$(BENCH_VENV)/bin/python -m pip install --quiet -e ".[bench]"
	touch $(BENCH_STAMP)

# The real-time iteration's rows need the native HPIPM (`make hpipm`): built first if missing.
bench: $(BENCH_STAMP)
	$(BENCH_VENV)/bin/python -m uuv_ocp.cli hpipm status | grep -q "HPIPM: /" \
		|| $(BENCH_VENV)/bin/python -m uuv_ocp.cli hpipm build
	$(BENCH_VENV)/bin/python -m benchmarks.run

# HPIPM and BLASFEO built for this CPU (about a minute; sources: a pinned PyPI sdist, checked by
# SHA-256).  Optional: the C real-time iteration links them when present (docs/solvers.md).
hpipm: $(STAMP)
	$(PY) -m uuv_ocp.cli hpipm build

# The paper's experiment (docs/paper.md): report, figures and verdicts in docs/reproduction/.
# Resumable: rerun after Ctrl-C.  `make reproduce QUICK=1` (or `make reproduce-quick`) is the
# reduced size that CI runs.
.PHONY: reproduce reproduce-quick
reproduce: $(STAMP)
	$(PY) -m uuv_ocp.cli reproduce --out docs/reproduction $(if $(QUICK),--quick)

reproduce-quick: $(STAMP)
	$(PY) -m uuv_ocp.cli reproduce --out docs/reproduction --quick

# ruff, mypy and the stubs they need come from the `lint` extra (versions in pyproject.toml).
# All four checks run (so one run reports everything); the target fails if any of them does.
# The last is the layer rule: no import cycle in src/uuv_ocp, counting imports inside functions.
LINT_PATHS := src tests benchmarks examples $(wildcard docs/tutorials/*.py)
LINT_STAMP := $(VENV)/.lint-installed

$(LINT_STAMP): $(STAMP) pyproject.toml
	$(PY) -m pip install --quiet -e ".[lint]"
	touch $(LINT_STAMP)

lint: $(LINT_STAMP)
	@status=0; \
	$(VENV)/bin/ruff check $(LINT_PATHS) || status=1; \
	$(VENV)/bin/ruff format --check $(LINT_PATHS) || status=1; \
	$(VENV)/bin/mypy src/uuv_ocp || status=1; \
	$(PY) -m benchmarks.import_graph --check || status=1; \
	exit $$status

# The documentation site (mkdocs.yml) into build/site.  --strict: a broken link or anchor, a
# missing tutorial snippet or an API reference mkdocstrings cannot resolve fails the target.
DOCS_STAMP := $(VENV)/.docs-installed

$(DOCS_STAMP): $(STAMP) pyproject.toml
	$(PY) -m pip install --quiet -e ".[docs]"
	touch $(DOCS_STAMP)

docs: $(DOCS_STAMP)
	NO_MKDOCS_2_WARNING=1 $(PY) -m mkdocs build --strict -d build/site

clean:
	rm -rf $(VENV) $(BENCH_VENV) out build .pytest_cache
