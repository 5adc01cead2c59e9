# The two Quick-start commands (README): `make demo` and `make test`.
# Each creates .venv with the project's own dependencies, so a fresh machine needs only
# Python >= 3.11, pip and git.
PYTHON ?= python3
VENV   ?= .venv
BIN    := $(VENV)/bin

.PHONY: demo test bench install clean

$(BIN)/.installed: pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e ".[test,plots]"
	touch $@

install: $(BIN)/.installed

demo: install
	$(BIN)/snan-hil demo

test: install
	$(BIN)/python -m pytest

bench: install
	$(BIN)/python bench/run_all.py

clean:
	rm -rf $(VENV) build *.egg-info
