# Two commands do everything on a fresh clone: `make demo` and `make test`.
PYTHON ?= python3
VENV   := .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed

.PHONY: venv demo test clean

venv: $(STAMP)

# Re-install when the pins or the package metadata change.
$(STAMP): requirements.txt requirements-dev.txt setup.py setup.cfg package.xml
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -r requirements-dev.txt
	$(PY) -m pip install --quiet --no-deps -e .
	touch $(STAMP)

demo: $(STAMP)
	$(VENV)/bin/star-tracker demo --duration 30 --output demo_output

test: $(STAMP)
	$(PY) -m pytest

clean:
	rm -rf build install log demo_output .pytest_cache

# Render-time benchmark (writes its section of docs/BENCHMARKS.md) and the simulator figures.
.PHONY: bench
bench: $(STAMP)
	$(PY) -m bench.bench_render --output docs/BENCHMARKS.md
	$(PY) -m bench.simulator_figures
