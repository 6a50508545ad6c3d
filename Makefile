# fpv-station: set up and run from a fresh machine.
#   make run    set up .venv and start the ground station on the embedded digital twin
#   make test   set up .venv (and Debian's chromium for the browser tests) and run every test
#   make test-fast   the REST contracts in-process (pytest -m fast): no server, twin or browser
PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed
# The JavaScript linter's packages (package-lock.json), installed by npm ci.
NODE_STAMP := node_modules/.installed
HOST   ?= 0.0.0.0
PORT   ?= 8000

.PHONY: run test test-fast venv browser bench lint lint-js clean

$(STAMP): pyproject.toml
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install -q --upgrade pip
	$(BIN)/python -m pip install -q -e '.[test]'
	touch $(STAMP)

venv: $(STAMP)

# Browser tests drive Debian's chromium through Playwright (no browser download).
browser:
	@command -v chromium >/dev/null 2>&1 || { \
	  if [ "$$(id -u)" -eq 0 ]; then apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends chromium >/dev/null; \
	  else echo "chromium missing: run 'sudo apt-get install chromium'" >&2; exit 1; fi; }

run: $(STAMP)
	$(BIN)/fpv-station serve --source sim --host $(HOST) --port $(PORT)

# Whole files to each of the two processes (--dist loadfile): a module's fixtures (a twin
# station, a recorded flight, its Chromium) start once, not once in each process.
test: $(STAMP) browser
	$(BIN)/python -m pytest -q -n auto --maxprocesses 2 --dist loadfile

# One part alone by its marker (pyproject.toml): -m fast here; -m browser, -m twin,
# -m subprocess, or "not browser and not twin" the same way.
test-fast: $(STAMP)
	$(BIN)/python -m pytest -q -m fast

bench: $(STAMP)
	for b in benchmarks/*.py; do $(BIN)/python $$b || exit 1; done

$(NODE_STAMP): package.json package-lock.json
	npm ci --silent
	touch $(NODE_STAMP)

# The Python formatter, linter and type checker, as configured in pyproject.toml
# (tools/typecheck.py runs mypy), and ESLint on web/, as configured in eslint.config.mjs
# (CI runs this).
lint: $(STAMP) lint-js
	$(BIN)/python -m ruff format --check .
	$(BIN)/python -m ruff check .
	$(BIN)/python tools/typecheck.py

lint-js: $(NODE_STAMP)
	node_modules/.bin/eslint web/

clean:
	rm -rf $(VENV) build *.egg-info node_modules .mypy_cache
