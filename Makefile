# knode_swarm_ros: `make demo` and `make test` each create or reuse $(VENV).
# No system ROS 2 is needed: rclpy and the messages come from the ros-jazzy-* wheels.

VENV ?= .venv
PYTHON ?= python3
PY := $(VENV)/bin/python
VENV_PREFIX = $(abspath $(VENV))
PYTEST_ARGS ?=
# cpu (default): the CPU build of the pinned torch, from the configured pip sources or else
# PyTorch's CPU index, or a clear error (tools/torch_build.py); cuda: whatever pip resolves.
TORCH_BUILD ?= cpu

# Every ROS process started from here stays on this machine.
ROS_ENV = ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST \
          AMENT_PREFIX_PATH="$(VENV_PREFIX)$${AMENT_PREFIX_PATH:+:$$AMENT_PREFIX_PATH}"

.PHONY: all venv lint test fuzz demo demo-offline bench mutation clean distclean

all: test

venv: $(VENV)/.installed

# Re-run when the pins or the packaging change (the data files, config/ among them,
# are copied into $(VENV)/share at install time).
$(VENV)/.installed: Makefile requirements.txt requirements-robot.txt requirements-dev.txt setup.py setup.cfg package.xml tools/torch_build.py \
                    $(wildcard config/*)
	@test -x $(PY) || { echo "creating $(VENV) with $$(command -v $(PYTHON)) ($$($(PYTHON) --version 2>&1))"; \
	  $(PYTHON) -m venv $(VENV); }
	$(PY) -m pip install --upgrade pip
	TORCH_BUILD=$(TORCH_BUILD) $(PY) tools/torch_build.py
	$(PY) -m pip install -r requirements-dev.txt
	$(PY) -m pip install -e . --no-deps
	@# An editable install leaves out setup.py's data_files (the ament index marker,
	@# package.xml, config/): copy them into the venv prefix, where ament_index_python
	@# finds them with AMENT_PREFIX_PATH=$(VENV_PREFIX).
	$(PY) -W ignore setup.py --quiet install_data --install-dir "$(VENV_PREFIX)" --force
	@touch $@

# ruff.toml: pyflakes, pycodestyle, import order, single quotes; the format is ruff's.
lint: $(VENV)/.installed
	$(VENV)/bin/ruff check .
	$(VENV)/bin/ruff format --check .

test: $(VENV)/.installed lint
	$(ROS_ENV) $(PY) -m pytest -q -rs tests $(PYTEST_ARGS)

# The main job: the shipped flock2d policy on 10 robots, one OS process per agent plus the
# simulator and the recorder (lockstep), then the metrics of the recorded run and a figure.
demo: $(VENV)/.installed
	$(ROS_ENV) $(VENV)/bin/swarm --scenario flock2d --robots 10 --steps 2000 --mode lockstep \
	  --record out/demo/swarm_flock2d.npz --figure out/demo/swarm_flock2d.png

# Without ROS: data, offline rollouts of the shipped policy against the ground truth.
demo-offline: $(VENV)/.installed
	$(ROS_ENV) $(PY) -m training.demo

bench: $(VENV)/.installed
	@set -e; found=0; for f in bench/*.py; do \
	  [ -f "$$f" ] || continue; found=1; echo "== $$f"; \
	  $(ROS_ENV) PYTHONPATH="$(CURDIR)$${PYTHONPATH:+:$$PYTHONPATH}" $(PY) "$$f"; \
	done; [ $$found = 1 ] || echo "no benchmarks under bench/"

# The suite's fuzz tests (tests/test_fuzz.py) with the `fuzz` hypothesis profile: FUZZ_EXAMPLES (10,000)
# generated inputs per reader and a fresh seed each run instead of the suite's fixed one (docs/testing.md,
# "Fuzzing"); PYTEST_ARGS='-k bag' picks readers.
FUZZ_EXAMPLES ?= 10000
fuzz: $(VENV)/.installed
	$(ROS_ENV) HYPOTHESIS_PROFILE=fuzz FUZZ_EXAMPLES=$(FUZZ_EXAMPLES) $(PY) -m pytest -q -rs tests/test_fuzz.py $(PYTEST_ARGS)

# Mutation testing (not part of CI; ~6300 mutants, hours on 2 cores, see docs/testing.md): cosmic-ray over
# the core and the *_logic modules, in a copy under out/mutation. MUTATION_ARGS: --only, --sample, --seed.
mutation: $(VENV)/.installed
	$(VENV)/bin/python -m pip install -q -r requirements-mutation.txt
	$(ROS_ENV) nice -n 10 $(PY) tools/mutation.py $(MUTATION_ARGS)

clean:
	rm -rf build install log .pytest_cache *.egg-info
	find . \( -path ./.git -o -path ./$(VENV) \) -prune -o -name __pycache__ -type d -prune -exec rm -rf {} +

distclean: clean
	rm -rf $(VENV)
