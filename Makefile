# Set-up and main jobs; README.md documents `make bench` and `make test`.
PYTHON ?= python3
VENV ?= .venv
# CPU build of torch first (on these machines `torch==2.13.0` is a local CPU wheel); override
# e.g. TORCH_SPEC="torch --index-url https://download.pytorch.org/whl/cpu" elsewhere.
TORCH_SPEC ?= torch==2.13.0
BIN := $(VENV)/bin
PIP := $(BIN)/python -m pip
STAMP := $(VENV)/.stcgym-installed

.PHONY: install bench bench-standard bench-full test test-explore test-latest lint perf docs clean clean-cache

$(BIN)/python:
	$(PYTHON) -m venv $(VENV)
	$(PIP) install -q --upgrade pip

$(STAMP): $(BIN)/python pyproject.toml
	$(PIP) install -q "$(TORCH_SPEC)"
	$(PIP) install -q -e ".[all]"
	touch $(STAMP)

install: $(STAMP)

bench: install
	$(BIN)/stcgym bench --quick

bench-standard: install
	$(BIN)/stcgym bench --standard

bench-full: install
	$(BIN)/stcgym bench --full

# The second run repeats the tests that compare two code paths (marker `equality`) under
# another OpenBLAS kernel: OpenBLAS picks kernels by CPU, and a claim of equality that holds
# only for this CPU's kernels must fail here, not on a user's machine. Prescott (SSE3) runs on
# every x86-64 CPU and differs from what any AVX2/AVX-512 CPU picks by default.
test: install
	MPLBACKEND=Agg $(BIN)/python -m pytest -n 2 --dist worksteal -q
	@if [ "$$(uname -m)" = x86_64 ]; then \
		echo "equality tests again under OPENBLAS_CORETYPE=Prescott:"; \
		OPENBLAS_CORETYPE=Prescott MPLBACKEND=Agg $(BIN)/python -m pytest -n 2 --dist worksteal -q -m equality; \
	fi

# Property tests with fresh random examples (and more of them): `make test` draws the same
# examples every run (tests/conftest.py), this target looks for new counter-examples.
test-explore: install
	MPLBACKEND=Agg $(BIN)/python -m pytest -n 2 --dist worksteal -q --hypothesis-profile=explore

# The suite on the newest numba (and llvmlite) of the registry, past pyproject.toml's upper
# bound: a numba release that breaks an assumption of stcgym.lanes.numba_internals fails
# tests/test_numba_internals.py here before it reaches a user. Its own venv and kernel cache.
LATEST_VENV ?= .venv-latest
test-latest:
	$(MAKE) install VENV=$(LATEST_VENV)
	$(LATEST_VENV)/bin/python -m pip install -q --upgrade numba llvmlite
	$(LATEST_VENV)/bin/python -c "import numba; print('numba', numba.__version__)"
	NUMBA_CACHE_DIR=$(CURDIR)/.numba-cache-latest MPLBACKEND=Agg \
		$(LATEST_VENV)/bin/python -m pytest -n 2 --dist worksteal -q

perf: install
	$(BIN)/python benchmarks/perf.py

# The documentation site, warnings as errors; the gallery executes every examples/plot_*.py.
docs: install
	cd docs && MPLBACKEND=Agg ../$(BIN)/python -m sphinx -W --keep-going -b html . _build/html

lint: install
	$(BIN)/ruff check . && $(BIN)/ruff format --check .

# Empties the numba cache of the kernels by hand; an edited kernel source empties it on the next
# import anyway (stcgym.lanes.kernel_cache), so this is only needed to measure a cold start.
clean-cache:
	find lanes envs adaptive agents -name '*.nbi' -delete -o -name '*.nbc' -delete

clean: clean-cache
	rm -rf $(VENV) .venv-latest .numba-cache-latest build *.egg-info .pytest_cache .hypothesis docs/_build docs/generated docs/gallery docs/sg_execution_times.rst
