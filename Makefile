SHELL = /bin/bash
PYTHON ?= python
# A CPU build of torch, installed before anything can pull the multi-GB CUDA build.
TORCH_VERSION ?= 2.13.0
PIP = $(PYTHON) -m pip install --quiet --disable-pip-version-check

.PHONY: install main test pytest lint format check-codestyle commit-checks benchmark-env

install:
	$(PIP) "torch==$(TORCH_VERSION)"
	$(PIP) -e ".[tests]"

# The main job: for now a scripted patrol of the default reserve, printing the team metrics.
main: install
	$(PYTHON) zoo/patrol.py --policy random --episodes 3 --seed 0
	$(PYTHON) zoo/patrol.py --policy stalest_block --episodes 3 --seed 0

pytest:
	$(PYTHON) -m pytest -n 2 tests

test: install lint pytest

lint:
	$(PYTHON) -m ruff check .

format:
	$(PYTHON) -m ruff check . --fix

check-codestyle: lint

commit-checks: lint pytest

benchmark-env: install
	$(PIP) -e ".[tests,bench]"
	$(PYTHON) benchmarks/env_speed.py
