# vacc: `make demo` runs the main job, `make test` runs the tests. Both install first.
PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed

.PHONY: install test test-fast test-integration lint demo bench clean

# Both cores: pytest-xdist runs tests in 3 workers (spawned servers bind port 0, so
# parallel tests never share a port; Ray instances side by side are fine). A third worker
# fills the time the others wait on sockets and timers: 9 min 13 s against 9 min 50 s with 2
# on a 2-core host, the same CPU. The 25 slowest tests are printed at the end.
JOBS   ?= 3
# Compiled modules are cached under the venv even where PYTHONDONTWRITEBYTECODE is set: the
# suite starts some 600 Python processes, and each would otherwise compile vacc (and pytest
# re-write every test module's asserts) again.
PYTEST := env -u PYTHONDONTWRITEBYTECODE PYTHONPYCACHEPREFIX=$(CURDIR)/$(VENV)/pycache $(BIN)/python -m pytest -q -n $(JOBS) --durations=25

install: $(STAMP)

$(STAMP): pyproject.toml constraints.txt
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install -q --upgrade pip
	$(BIN)/python -m pip install -q -c constraints.txt -e '.[dev]'
	touch $(STAMP)

test: install
	$(PYTEST)

# The unit tier: in-process tests only (tests/conftest.py sorts them), without the slow ones.
test-fast: install
	$(PYTEST) -m "unit and not slow"

test-integration: install
	$(PYTEST) -m integration

lint: install
	$(BIN)/ruff check .
	$(BIN)/mypy

demo: install
	$(BIN)/vacc demo

bench: install
	$(BIN)/python -m pip install -q -c constraints.txt -e '.[dev,bench]'
	$(BIN)/vacc bench --json runs/bench.json

clean:
	rm -rf $(VENV) runs .pytest_cache .ruff_cache .mypy_cache
