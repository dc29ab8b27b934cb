# Two commands set everything up on a fresh machine:
#   make demo   creates .venv if missing, installs hritest, runs the main job on a bundled spec
#   make test   creates .venv if missing, installs hritest with its test tools, runs the tests
PYTHON ?= $(shell command -v python3.11 || command -v python3)
VENV ?= .venv
BIN := $(VENV)/bin

# torch goes first and alone, pinned: pip then takes the CPU wheel on disk instead of
# resolving a multi-GB CUDA build for a bare `torch` requirement.
$(BIN)/hritest: pyproject.toml
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install -q --disable-pip-version-check torch==2.13.0
	$(BIN)/python -m pip install -q --disable-pip-version-check -e '.[test]'
	touch $@

.PHONY: demo test
# The main job, small: DSAS on the collaboration domain, 250 real evaluations, a short inner loop.
# hritest search exits 1 when it finds failures, which is the point of the demo, not an error.
demo: $(BIN)/hritest
	$(BIN)/hritest validate specs/*.yaml
	$(BIN)/hritest show specs/collab.yaml
	$(BIN)/hritest check specs/collab.yaml
	$(BIN)/hritest search specs/collab.yaml --algorithm dsas --budget 250 --inner-iterations 100 \
		|| test $$? -eq 1

# Lint, formatting and the import layers (pyproject's [tool.ruff] and [tool.importlinter]) first:
# they take seconds, the tests minutes.
test: $(BIN)/hritest
	$(BIN)/ruff check .
	$(BIN)/ruff format --check .
	$(BIN)/lint-imports
	$(BIN)/python -m pytest
