# vfcli: make demo | make test | make bench | make schemas
PYTHON ?= python3.11
VENV   ?= .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed
DEMO   ?= demo

.PHONY: venv demo test bench schemas clean

venv: $(STAMP)

$(STAMP): pyproject.toml
	@command -v $(PYTHON) >/dev/null 2>&1 || { echo "error: $(PYTHON) not found; set PYTHON=/path/to/python3.11" >&2; exit 2; }
	@test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[test,viz]'
	@touch $(STAMP)

demo: venv
	@bash examples/demo.sh $(DEMO)

test: venv
	$(BIN)/python -m pytest -q

bench: venv
	@for b in bench/bench_*.py; do echo "== $$b"; $(BIN)/python $$b || exit 1; done

schemas: venv
	$(BIN)/vfcli schemas --out schemas --layout-doc docs/store-layout.md --example examples/recording.toml

clean:
	rm -rf $(VENV) $(DEMO) .pytest_cache
