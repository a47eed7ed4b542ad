# One command sets everything up and does the job: `make demo` (main job on the simulated arm), `make test`.
PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed

.PHONY: setup demo test lint bench clean

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/pip install --quiet --upgrade pip
	$(BIN)/pip install --quiet -e '.[test]'
	touch $(STAMP)

setup: $(STAMP)

## demo: set up, run the thesis' rotation test on the simulated arm, and write its report
demo: $(STAMP)
	$(BIN)/wamctl run configs/rotation.yaml

## test: set up, check the code (ruff, the import layers) and run the whole test suite
test: lint
	$(BIN)/python -m pytest -q

## lint: ruff and the layer contract of docs/architecture.md (import-linter)
lint: $(STAMP)
	$(BIN)/ruff check wamctl tests benchmarks
	$(BIN)/lint-imports

## bench: speed figures (simulator, friction sweep, diagnosis, CAN loop, gaze chain, peer simulator)
bench: $(STAMP)
	$(BIN)/pip install --quiet -e '.[bench]'
	for b in benchmarks/bench_*.py; do echo "== $$b"; $(BIN)/python $$b || exit 1; done

clean:
	rm -rf $(VENV) build *.egg-info
