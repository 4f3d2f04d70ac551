# Two commands for a newcomer: `make demo` and `make test`. Both create or reuse .venv.
PYTHON ?= python3.11
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
export MLFLOW_DISABLE_TELEMETRY := true
export MPLBACKEND := Agg

.PHONY: demo test bench lint docs install clean

install: $(STAMP)

# torch is installed first on its own pin so no other requirement can pull a CUDA build.
$(STAMP): pyproject.toml
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install -q --upgrade pip
	$(BIN)/python -m pip install -q torch==2.13.0
	$(BIN)/python -m pip install -q -e '.[dev]'
	touch $(STAMP)

# Exit 3 means an alert fired: the demo's drift step sets its limit low to show one.
demo: $(STAMP)
	$(BIN)/backlash run experiments/demo.toml || [ $$? -eq 3 ]

# -rs prints why a test was skipped (the browser test without Chromium, PostgreSQL tests);
# -n 2 runs the tests on two processes (the machines have two cores; about 9 minutes).
test: $(STAMP)
	$(BIN)/python -m pytest -rs -n 2

bench: $(STAMP)
	$(BIN)/python -m bench

# The manual in docs/, built strictly (a broken link or a stale API name fails the build).
docs: $(STAMP)
	$(BIN)/mkdocs build --strict -d site

lint: $(STAMP)
	$(BIN)/ruff check pipeline features models experiments tests bench

clean:
	rm -rf $(VENV) site mlruns mlflow.db mlflow.db.lock mlartifacts .pytest_cache
