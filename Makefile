# Two entry points for a fresh machine; each installs what it needs into .venv first.
PY ?= python3.11
VENV := .venv
BIN := $(VENV)/bin

.PHONY: install install-chromium run test test-slow pin

$(BIN)/seal: pyproject.toml
	test -x $(BIN)/python || $(PY) -m venv $(VENV)
	$(BIN)/pip install -q --upgrade pip
	$(BIN)/pip install -q -e ".[test]"
	touch $(BIN)/seal

# The HTML report test drives headless Chromium (Debian package `chromium`). Installed only when
# missing, so repeat runs cost nothing; as root directly, otherwise through passwordless sudo. If it
# cannot be installed the make stops here, saying so: that test fails rather than skips.
CHROMIUM ?= /usr/bin/chromium
SUDO := $(shell [ "$$(id -u)" = 0 ] || echo sudo -n)
install-chromium:
	@test -x $(CHROMIUM) || { command -v apt-get >/dev/null \
	  && $(SUDO) env DEBIAN_FRONTEND=noninteractive sh -c 'apt-get update -qq && apt-get install -y -qq chromium' >/dev/null \
	  || { echo "error: could not install chromium (Debian package 'chromium'); install it, or pass" \
	            "CHROMIUM=/path/to/chromium. The HTML report test needs a real browser." >&2; exit 1; }; }

install: $(BIN)/seal install-chromium

# SEAL steering the shipped learned reasoning VLA (fast render, the model it was trained in) with the
# oracle verifier: ~35 s on the 2-core machine (docs/performance.md, "make run").
run: install
	$(BIN)/seal run --suite libero_10 --task 5 --method seal --k 10 --policy vla --verifier oracle --out runs/demo

# Two test processes, one test file each at a time (`--dist loadfile`: a file's module fixtures, such
# as a simulator pool, are built once). ~13 min on the 2-core machine under load (docs/performance.md).
test: install
	$(BIN)/python -m pytest -q -n 2 --dist loadfile --durations=15

# The long tests kept out of `make test` (marked slow): full expert episodes (microwave, books,
# ketchup, every composition task) and the checks of every task of every derived suite.
# ~7 min (410 s) on the 2-core development machine (docs/performance.md, "Slow tests").
test-slow: install
	$(BIN)/python -m pytest -q -m slow

# Long jobs (training, DAgger rounds, 50-trial evaluations) run a pinned copy of the code: a worktree
# of HEAD under ../runs/code/<commit>, put first on the path by the printed PYTHONPATH. Work on this
# checkout then cannot change what a running job imports halfway through (docs/dagger.md).
RUNS ?= ../runs
pin:
	@sha=$$(git rev-parse --short HEAD); dir=$(RUNS)/code/$$sha; \
	  [ -d $$dir ] || git worktree add --detach $$dir HEAD >/dev/null 2>&1 || { echo "error: could not make $$dir" >&2; exit 1; }; \
	  echo "export PYTHONPATH=$$(cd $$dir && pwd)/src"
