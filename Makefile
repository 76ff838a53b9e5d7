# One-command set-up, demo and tests. Everything lives in .venv inside the repository.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.setup-stamp
# numba compiles the stage-1 loops and the scan simulator; tqdm draws progress bars (see README).
RUNTIME_DEPS := 'ros-jazzy-rclpy[fastrtps]==7.1.6' ros-jazzy-common-interfaces==5.3.6 'rosbags>=0.10' numpy numba tqdm
# pyyaml: the tests read the parameter YAML and bag metadata; rerun-sdk: pass3d_view (optional for users) is tested.
TEST_DEPS := pytest pytest-timeout ruff pyyaml rerun-sdk

.PHONY: setup demo test lint bench clean

setup: $(STAMP)

# torch first and pinned: an unpinned torch pulls several GB of CUDA wheels.
$(STAMP): setup.py package.xml Makefile
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet torch==2.13.0
	$(BIN)/python -m pip install --quiet $(RUNTIME_DEPS) $(TEST_DEPS)
	$(BIN)/python -m pip install --quiet --no-deps -e .
	touch $(STAMP)

# SENSOR=vlp16 (or vlp32c, hdl32e, os1-64, os1-128, pandar64) drives a simulated drive of that LiDAR.
demo: setup
	$(BIN)/python -m pass3d_ros.tools.demo $(if $(SENSOR),--sensor $(SENSOR))

test: setup
	$(BIN)/python -m pytest -q test

lint: setup
	$(BIN)/ruff check pass3d_ros test launch_configs

bench: setup
	$(BIN)/pass3d_benchmark codec

clean:
	rm -rf $(VENV) build install log *.egg-info .pytest_cache .ruff_cache
