# One-command set-up, demo and tests. Everything lives in .venv inside the repository.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.setup-stamp
# pytest processes for the tests (pytest-xdist; each has its own DDS domains, see test/helpers/ros.py).
JOBS ?= 2
PYTEST := $(BIN)/python -m pytest -q -n $(JOBS) --dist loadfile

.PHONY: setup demo test test-slow lint bench clean

setup: $(STAMP)

# The dependencies are listed once, in setup.py (runtime, and the ros-wheels, torch and test extras). torch first, pinned as setup.py pins
# it: an unpinned torch pulls several GB of CUDA wheels.
$(STAMP): setup.py package.xml Makefile
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet torch==2.13.0
	$(BIN)/python -m pip install --quiet -e '.[ros-wheels,torch,test]'
	touch $(STAMP)

# SENSOR=vlp16 (or vlp32c, hdl32e, os1-64, os1-128, pandar64) drives a simulated drive of that LiDAR.
demo: setup
	$(BIN)/python -m pass3d_ros.tools.demo $(if $(SENSOR),--sensor $(SENSOR))

# Every test but those marked slow; `make test-slow` runs those, CI (.ci/run) both.
test: setup
	$(PYTEST) -m "not slow" test

test-slow: setup
	$(PYTEST) -m slow test

lint: setup
	$(BIN)/ruff check pass3d_ros test launch_configs

bench: setup
	$(BIN)/pass3d_benchmark codec

clean:
	rm -rf $(VENV) build install log *.egg-info .pytest_cache .ruff_cache
