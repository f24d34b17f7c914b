# Set-up and checks. `make install` then `make test` is all a newcomer needs.
PY ?= python3
VENV := .venv
BIN := $(VENV)/bin

.PHONY: install test test-slow test-explore lint bench fixtures clean

install:
	$(PY) -m venv $(VENV)
	$(BIN)/pip install --quiet --upgrade pip
	$(BIN)/pip install --quiet -e '.[dev]'

test:
	$(BIN)/python -m pytest -q

test-explore:
	$(BIN)/python -m pytest -q tests/core tests/test_substitute.py tests/test_untrim.py --hypothesis-profile=explore

test-slow:
	$(BIN)/python -m pytest -q -m slow

lint:
	$(BIN)/ruff check watertight_cli tests benchmarks fixtures

bench:
	$(BIN)/python -m benchmarks

fixtures:
	$(BIN)/python fixtures/make_fixtures.py

clean:
	rm -rf $(VENV) build *.egg-info .pytest_cache .hypothesis
