# One-command set-up, demo and tests. Everything lives in .venv inside the repository.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.setup-stamp

.PHONY: setup demo test lint bench clean

setup: $(STAMP)

# torch first and pinned: an unpinned torch pulls several GB of CUDA wheels.
$(STAMP): setup.py package.xml requirements.txt
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet torch==2.13.0
	$(BIN)/python -m pip install --quiet -r requirements.txt
	$(BIN)/python -m pip install --quiet --no-deps -e .
	touch $(STAMP)

demo: setup
	$(BIN)/python -m pass3d_ros.tools.demo

test: setup
	$(BIN)/python -m pytest -q test

lint: setup
	$(BIN)/ruff check pass3d_ros test launch_configs

bench: setup
	$(BIN)/pass3d_benchmark codec

clean:
	rm -rf $(VENV) build install log *.egg-info .pytest_cache .ruff_cache
