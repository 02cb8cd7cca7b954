# Two entry points for a fresh machine; each installs what it needs into .venv first.
PY ?= python3.11
VENV := .venv
BIN := $(VENV)/bin

.PHONY: install install-chromium run test

$(BIN)/seal: pyproject.toml
	test -x $(BIN)/python || $(PY) -m venv $(VENV)
	$(BIN)/pip install -q --upgrade pip
	$(BIN)/pip install -q -e ".[test]"
	touch $(BIN)/seal

# The HTML report test drives headless Chromium (Debian package `chromium`). Installed only when
# missing, so repeat runs cost nothing; as root directly, otherwise through passwordless sudo. If it
# cannot be installed the make goes on and that one test skips, saying why.
CHROMIUM ?= /usr/bin/chromium
SUDO := $(shell [ "$$(id -u)" = 0 ] || echo sudo -n)
install-chromium:
	@test -x $(CHROMIUM) || { command -v apt-get >/dev/null \
	  && $(SUDO) env DEBIAN_FRONTEND=noninteractive sh -c 'apt-get update -qq && apt-get install -y -qq chromium' >/dev/null \
	  || echo "warning: could not install chromium; the HTML report test will be skipped" >&2; }

install: $(BIN)/seal install-chromium

run: install
	$(BIN)/seal run --suite libero_10 --task 0 --method seal --k 10 --verifier oracle --out runs/demo

test: install
	$(BIN)/python -m pytest -q
