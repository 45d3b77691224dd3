# undertow: every target sets up what it needs on a fresh machine.
PYTHON ?= python3
VENV   ?= .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed
HOST   ?= 127.0.0.1
PORT   ?= 8000
PYTEST_ARGS ?=

.PHONY: install serve test test-slow openapi screenshot clean

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e '.[test,bench]'
	touch $(STAMP)

install: $(STAMP)

serve: $(STAMP)
	$(PY) -m uvicorn app.main:app --host $(HOST) --port $(PORT) --http app.server:HeadTimeoutProtocol

test: $(STAMP)
	$(PY) -m pytest -n 2 $(PYTEST_ARGS)

test-slow: $(STAMP)
	$(PY) -m pytest -n 2 -m slow $(PYTEST_ARGS)

openapi: $(STAMP)
	$(PY) -m app.openapi_export openapi/openapi.json

screenshot: $(STAMP)
	UNDERTOW_SCREENSHOT=1 $(PY) -m pytest tests/test_viewer.py -k watch_it -p no:xdist

clean:
	rm -rf $(VENV) build *.egg-info .pytest_cache
