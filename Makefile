# Two commands set up a fresh machine and run everything: `make demo` and `make test`.
VENV ?= .venv
PY := $(VENV)/bin/python
EXTRAS ?= sim,viz,data,hf,dev
PYTEST_ARGS ?= -n 2

.PHONY: setup demo demo-check test lint bench clean lerobot-lane

setup:
	@EXTRAS=$(EXTRAS) VENV=$(VENV) bash scripts/setup.sh

demo: setup
	$(VENV)/bin/gazereg experiment --preset demo

# The main job, then a check that its numbers match docs/main-job.md's demo block (CI runs this).
demo-check: demo
	$(PY) scripts/update_results.py runs/demo --check

RUFF_PATHS := src tests benchmarks examples scripts lerobot_plugin tests_lerobot tests_aloha

test: setup
	$(VENV)/bin/ruff check $(RUFF_PATHS)
	$(VENV)/bin/ruff format --check $(RUFF_PATHS)
	$(PY) -m pytest $(PYTEST_ARGS)

lint: setup
	$(VENV)/bin/ruff check $(RUFF_PATHS)
	$(VENV)/bin/ruff format --check $(RUFF_PATHS)

bench: setup
	$(PY) benchmarks/run_all.py

# LeRobot (Python >= 3.12) lane: its own cached venv in ~/.cache/gazereg; skipped where no Python 3.12 exists.
lerobot-lane:
	bash scripts/lerobot_lane.sh

clean:
	rm -rf $(VENV) .pytest_cache build *.egg-info src/*.egg-info
