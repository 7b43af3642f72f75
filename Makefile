# vfcli: make demo | make test | make bench | make schemas
PYTHON ?= python3.11
VENV   ?= .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed
DEMO   ?= demo

.PHONY: venv browser demo test bench schemas clean

# Python's own bytecode cache, even where the environment turns it off (PYTHONDONTWRITEBYTECODE=1 in
# many container images): every `vfcli` process and test worker otherwise compiles vfcli's modules
# again, 0.13 s of each command's start and 4-6 s of each worker's collection (docs/benchmarks.md,
# "The suite's time (session 26)"). The caches go under the venv, not into the source tree
# (`make clean` removes them with it).
unexport PYTHONDONTWRITEBYTECODE
export PYTHONPYCACHEPREFIX := $(abspath $(VENV))/pycache

venv: $(STAMP)

# --no-compile: pip would byte-compile every module of every package (all of scipy's, VTK's and dask's tests
# among them), 27 of the install's 60 s here (warm pip cache); the modules a command imports are compiled at
# their first import instead, into the cache above (docs/benchmarks.md, "Session 73: the install, and the
# steady state's transfers in one product").
$(STAMP): pyproject.toml
	@command -v $(PYTHON) >/dev/null 2>&1 || { echo "error: $(PYTHON) not found; set PYTHON=/path/to/python3.11" >&2; exit 2; }
	@test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet --no-compile -e '.[export,test,viz,workflow]'
	@touch $(STAMP)

demo: venv
	@bash examples/demo.sh $(DEMO)

# headless Chromium for tests/test_report_browser.py: Debian's package (apt needs root, or sudo)
CHROMIUM ?= /usr/bin/chromium
browser:
	@test -x $(CHROMIUM) || { \
	  if [ "$$(id -u)" = 0 ]; then apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium; \
	  elif command -v sudo >/dev/null 2>&1; then sudo apt-get update -qq && sudo DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium; \
	  else echo "error: $(CHROMIUM) missing; install Debian's chromium package as root (apt-get install chromium)" >&2; exit 2; fi; }

# both cores, each test file on one worker (its fixtures built once); the 15 slowest steps listed.
# A third worker gains 2-3 % (docs/benchmarks.md, "Session 64: the suite's time, two workers or three").
# One BLAS thread per process: two workers already fill two cores, and OpenBLAS's threads beside
# other busy processes made a diagnose test file 1.6x slower (docs/benchmarks.md, "The suite's
# time and diagnose's kernels").
test: venv browser
	OPENBLAS_NUM_THREADS=1 OMP_NUM_THREADS=1 MKL_NUM_THREADS=1 $(BIN)/python -m pytest -q -n 2 --dist loadfile --durations=15

# a benchmark that needs inputs (kept stores, seeds, the demo's store) exits 2 with its usage and is passed over;
# its docstring and docs/benchmarks.md say how to run it
bench: venv
	@for b in bench/bench_*.py; do echo "== $$b"; $(BIN)/python $$b; rc=$$?; \
	  if [ $$rc -eq 2 ]; then echo "   (needs inputs: passed over)"; elif [ $$rc -ne 0 ]; then exit 1; fi; done

schemas: venv
	$(BIN)/vfcli schemas --out schemas --layout-doc docs/store-layout.md --example examples/recording.toml

clean:
	rm -rf $(VENV) $(DEMO) .pytest_cache
