# undertow: every target sets up what it needs on a fresh machine.
PYTHON ?= python3
VENV   ?= .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed
HOST   ?= 127.0.0.1
PORT   ?= 8000
PYTEST_ARGS ?=

# Pinned for Python 3.11 on linux x86_64 by `make lock`: the image installs runtime.txt,
# the venv (tests, lint) dev.txt, which holds the same versions plus the test and dev extras.
LOCK_RUNTIME := requirements/runtime.txt
LOCK_DEV     := requirements/dev.txt
LOCK_FLAGS   := --quiet --python-version 3.11 --python-platform x86_64-unknown-linux-gnu

.PHONY: install serve test test-slow lint lock browser openapi screenshot clean postgres-server

$(STAMP): pyproject.toml $(LOCK_DEV)
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -r $(LOCK_DEV)
	$(PY) -m pip install --quiet --no-deps -e .
	touch $(STAMP)

install: $(STAMP)

serve: $(STAMP)
	$(PY) -m uvicorn app.main:app --host $(HOST) --port $(PORT) --http app.server:HeadTimeoutProtocol

# The store tests start a throwaway PostgreSQL server of their own; its binaries come from
# Debian's postgresql package, installed here when missing and when run as root (else
# those tests skip, saying why).
postgres-server:
	@if ! ls /usr/lib/postgresql/*/bin/initdb >/dev/null 2>&1 && [ -z "$$UNDERTOW_PG_BIN" ]; then \
	  if [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1; then \
	    echo "installing Debian's postgresql for the job store tests"; \
	    apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq postgresql >/dev/null; \
	  else \
	    echo "no PostgreSQL server binaries: the PostgreSQL store tests will be skipped"; \
	  fi; \
	fi

# Each test module runs whole on one of the two workers (--dist loadscope): what a module
# builds once (NLPs, compiled derivatives, servers) is then built once, not once per worker.
test: $(STAMP) postgres-server
	$(PY) -m pytest -n 2 --dist loadscope $(PYTEST_ARGS)

test-slow: $(STAMP) postgres-server
	$(PY) -m pytest -n 2 --dist loadscope -m slow $(PYTEST_ARGS)

lint: $(STAMP)
	$(VENV)/bin/ruff check .
	$(VENV)/bin/mypy

# Re-resolve both lock files from pyproject.toml (newest versions within its bounds).
lock: $(STAMP)
	$(VENV)/bin/uv pip compile $(LOCK_FLAGS) --upgrade --extra test --extra bench --extra dev \
	    pyproject.toml -o $(LOCK_DEV)
	$(VENV)/bin/uv pip compile $(LOCK_FLAGS) --constraint $(LOCK_DEV) \
	    pyproject.toml -o $(LOCK_RUNTIME)

# Debian's chromium for tests/test_viewer.py (skipped without it); needs apt-get and root.
browser:
	test -x /usr/bin/chromium || { apt-get update -qq && DEBIAN_FRONTEND=noninteractive \
	    apt-get install -y -qq --no-install-recommends chromium >/dev/null; }

openapi: $(STAMP)
	$(PY) -m app.openapi_export openapi/openapi.json

screenshot: $(STAMP) browser
	UNDERTOW_SCREENSHOT=1 $(PY) -m pytest tests/test_viewer.py -k watch_it -p no:xdist

clean:
	rm -rf $(VENV) build *.egg-info .pytest_cache
