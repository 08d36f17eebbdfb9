# Two commands do everything on a fresh clone: `make demo` and `make test` (every test, the slow
# ones too); `make test-fast` leaves out the tests marked slow (pytest.ini) while developing.
PYTHON ?= python3
VENV   := .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed

.PHONY: venv demo test test-fast clean example-bag ros2cli

venv: $(STAMP)

# Re-install when the pins or the package metadata change.
$(STAMP): requirements.txt requirements-dev.txt setup.py setup.cfg package.xml pyproject.toml
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -r requirements-dev.txt
	$(PY) -m pip install --quiet --no-deps --no-build-isolation -e .  # pyproject's build requirements are installed already
	$(PY) -m star_tracker.warm_up  # compile the numba kernels now, not at the first node start
	touch $(STAMP)

demo: $(STAMP)
	$(VENV)/bin/star-tracker demo --duration 30 --output demo_output

# Two workers (pytest-xdist), each test file in one of them (the files' fixed ROS domains);
# `pytest` alone runs the same tests in one process.
test: $(STAMP) ros2cli
	$(PY) -m pytest -n 2 --dist loadfile

test-fast: $(STAMP)
	$(PY) -m pytest -m "not slow"

# The real ros2 CLI (ros2 run/launch/param/lifecycle/...) for test/package/test_ros2_cli.py, from the
# workplace's ../shared/ros2cli, installed into .venv only where that exists (elsewhere: nothing
# to do, and those tests skip); colcon-bash gives colcon builds their install/setup.bash.
ROS2CLI       := ../shared/ros2cli
ROS2CLI_STAMP := $(VENV)/.ros2cli-installed

ros2cli: $(if $(wildcard $(ROS2CLI)/install.sh),$(ROS2CLI_STAMP))

$(ROS2CLI_STAMP): $(STAMP) $(wildcard $(ROS2CLI)/install.sh)
	bash $(ROS2CLI)/install.sh $(VENV)
	$(PY) -m pip install --quiet colcon-bash==0.5.0
	touch $(ROS2CLI_STAMP)

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

.PHONY: bench datasheet
# The list of benchmarks, their order and options is star_tracker/commands/bench.py's BENCHES
# (`star-tracker bench --dry-run` prints the commands); BENCH_ARGS passes options, e.g.
# `make bench BENCH_ARGS="--only identify --no-peers"`.
bench: $(BENCH_STAMP)
	$(VENV)/bin/star-tracker bench $(BENCH_ARGS)

# The datasheet (docs/DATASHEET.md): the characterization campaigns on every local core (~10 min on
# two; resumable: run it again after an interruption), their figures copied into docs/, then the page.
datasheet: $(STAMP)
	$(VENV)/bin/star-tracker characterize datasheet --output characterize_output/datasheet --docs docs
	$(PY) -m bench.datasheet
