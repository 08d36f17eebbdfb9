# Two commands do everything on a fresh clone: `make demo` and `make test` (every test, the slow
# ones too); `make test-fast` leaves out the tests marked slow (pytest.ini) while developing.
PYTHON ?= python3
VENV   := .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed

.PHONY: venv demo test test-fast clean example-bag

venv: $(STAMP)

# Re-install when the pins or the package metadata change.
$(STAMP): requirements.txt requirements-dev.txt setup.py setup.cfg package.xml
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -r requirements-dev.txt
	$(PY) -m pip install --quiet --no-deps -e .
	$(PY) -m star_tracker.warm_up  # compile the numba kernels now, not at the first node start
	touch $(STAMP)

demo: $(STAMP)
	$(VENV)/bin/star-tracker demo --duration 30 --output demo_output

test: $(STAMP)
	$(PY) -m pytest

test-fast: $(STAMP)
	$(PY) -m pytest -m "not slow"

# A small example bag (4 s at 5 Hz through the three nodes, ~40 MiB), made by a command and
# never committed: `star-tracker play example_bag` replays it (README, docs/RECORD_REPLAY.md).
example-bag: example_bag/metadata.yaml

example_bag/metadata.yaml: $(STAMP)
	rm -rf example_bag example_output
	$(VENV)/bin/star-tracker demo --duration 4 --rate 5 --output example_output --record example_bag

clean:
	rm -rf build install log demo_output .pytest_cache example_bag example_output

# Benchmarks write their sections of docs/BENCHMARKS.md and the figures in docs/images.
# Peers (tetra3rs, cedar-solve) are optional bench dependencies, never runtime ones;
# cedar-solve declares numpy<2, so it goes in without its dependencies (it runs on ours).
BENCH_STAMP := $(VENV)/.bench-installed

$(BENCH_STAMP): requirements-bench.txt $(STAMP)
	$(PY) -m pip install --quiet -r requirements-bench.txt
	$(PY) -m pip install --quiet --no-deps cedar-solve==0.5.1
	touch $(BENCH_STAMP)

.PHONY: bench
bench: $(BENCH_STAMP)
	$(PY) -m bench.bench_render --output docs/BENCHMARKS.md
	$(PY) -m bench.simulator_figures
	$(PY) -m bench.bench_centroid --output docs/BENCHMARKS.md
	$(PY) -m bench.bench_identify --output docs/BENCHMARKS.md
	$(PY) -m bench.bench_databases --output docs/BENCHMARKS.md
	$(PY) -m bench.bench_attitude --output docs/BENCHMARKS.md
	$(PY) -m bench.bench_rate_aid --output docs/BENCHMARKS.md
	$(PY) -m bench.bench_tracking --output docs/BENCHMARKS.md
	$(PY) -m bench.bench_replay --output docs/BENCHMARKS.md
	$(PY) -m bench.bench_pipeline --output docs/BENCHMARKS.md
	$(PY) -m bench.bench_soak --minutes 10 --output docs/BENCHMARKS.md  # 10 min
	$(PY) -m bench.plots  # the benchmark plots from the JSON results above
