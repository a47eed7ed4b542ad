# One command sets everything up and does the job: `make demo` (main job on the simulated arm), `make test`.
PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed

.PHONY: setup browser demo test lint bench clean

$(STAMP): pyproject.toml constraints.txt
	@echo "setting up $(VENV) (first time, or after pyproject.toml changed): installing wamctl and its packages"
	@echo "(pinocchio, pandas, dask, matplotlib, ...); this takes about 2 minutes, pip shows its progress below"
	$(PYTHON) -m venv $(VENV)
	$(BIN)/pip install --quiet --upgrade pip
	$(BIN)/pip install --progress-bar on -c constraints.txt -e '.[test]'
	touch $(STAMP)
	@echo "$(VENV) is ready: $(BIN)/wamctl"

setup: $(STAMP)

## demo: set up, run the thesis' rotation test on the simulated arm, and write its report
demo: $(STAMP)
	$(BIN)/wamctl run configs/rotation.yaml

## browser: Debian's headless Chromium, for the test that renders every report (installed when missing; without
## it, that test is skipped and says why)
browser:
	@command -v chromium >/dev/null 2>&1 || command -v chromium-browser >/dev/null 2>&1 || \
	  { echo "installing chromium (apt-get) for tests/report/test_browser.py"; \
	    { DEBIAN_FRONTEND=noninteractive apt-get install -y -q chromium >/dev/null 2>&1 || \
	      { apt-get update -q >/dev/null 2>&1 && DEBIAN_FRONTEND=noninteractive apt-get install -y -q chromium >/dev/null 2>&1; } || \
	      sudo -n env DEBIAN_FRONTEND=noninteractive apt-get install -y -q chromium >/dev/null 2>&1; } || \
	    echo "chromium could not be installed here: the browser test will be skipped"; }

## test: set up, check the code (ruff, the import layers) and run the whole test suite, on every core (pytest-xdist)
test: lint browser
	$(BIN)/python -m pytest -q -n auto

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
