# Two entry points for a fresh machine; each installs what it needs into .venv first.
PY ?= python3.11
VENV := .venv
BIN := $(VENV)/bin

.PHONY: install run test

$(BIN)/seal: pyproject.toml
	test -x $(BIN)/python || $(PY) -m venv $(VENV)
	$(BIN)/pip install -q --upgrade pip
	$(BIN)/pip install -q -e ".[test]"
	touch $(BIN)/seal

install: $(BIN)/seal

run: install
	$(BIN)/seal run --suite libero_10 --task 0 --method seal --k 10 --verifier oracle --out runs/demo

test: install
	$(BIN)/python -m pytest -q
