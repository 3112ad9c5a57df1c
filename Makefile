# terrainml: two-command quick start (make demo, make test). Every target creates or refreshes .venv.
PY ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: demo test test-all bench venv clean

venv: $(STAMP)

# torch is installed first and pinned (CPU wheel); the extras then see it satisfied and never pull CUDA builds.
$(STAMP): pyproject.toml
	test -x $(BIN)/python || $(PY) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet "torch==2.13.0"
	$(BIN)/python -m pip install --quiet -e ".[cnn,dask,test,bench]" "torch==2.13.0"
	touch $(STAMP)

demo: $(STAMP)
	$(BIN)/terrainml demo --out runs/demo

# pytest caches its rewritten test modules (and Python its bytecode) in __pycache__: a machine that
# sets PYTHONDONTWRITEBYTECODE would rewrite all of them on every run (10 of the 21 s of collection)
test test-all: export PYTHONDONTWRITEBYTECODE :=

# the fast tier: the linter and the layers contract first (seconds), then every test not marked acceptance
test: $(STAMP)
	$(BIN)/ruff check terrainml tests benchmarks
	$(BIN)/lint-imports
	$(BIN)/python -m pytest -n 2 --timeout 600 -m "not acceptance" tests

# the acceptance tier, everything `make test` leaves out: real-data builds and replays, long
# simulations, real-time DDS (CI runs it after `make test`)
test-all: $(STAMP)
	$(BIN)/python -m pytest -n 2 --timeout 3600 -m acceptance tests

bench: $(STAMP)
	$(BIN)/python -m benchmarks.run_all --out BENCHMARKS.md

clean:
	rm -rf $(VENV) runs/demo
