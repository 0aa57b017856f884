VENV ?= .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed

.PHONY: demo test lint bench chaos soak clean ferretdb web

# FerretDB (MongoDB's wire protocol over SQLite), built from the Go module proxy at the
# version pinned in tools/ferretdb/go.mod: the tests' real MongoDB-driver path runs on it.
# FLEET_FERRETDB_BIN, when set, names the binary to use (built there if missing).
FERRETDB_VERSION := $(shell awk '$$1 == "github.com/FerretDB/FerretDB" { print $$2 }' tools/ferretdb/go.mod)
FERRETDB_BIN ?= $(or $(FLEET_FERRETDB_BIN),.cache/ferretdb/$(FERRETDB_VERSION)/bin/ferretdb)

$(STAMP): pyproject.toml
	test -x $(PY) || python3 -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	$(PY) -m pip install -q -e '.[all]'
	touch $(STAMP)

# The console's third-party files (Leaflet, Swagger UI), pinned in server/web/package-lock.json
# and served by the server from server/web/node_modules: no CDN, no bundler. Their install
# scripts are not run (none is needed; swagger-ui-dist's would report the install).
WEB_STAMP := server/web/node_modules/.package-lock.json

$(WEB_STAMP): server/web/package.json server/web/package-lock.json
	cd server/web && npm ci --ignore-scripts --no-audit --no-fund
	touch $(WEB_STAMP)

web: $(WEB_STAMP)

$(FERRETDB_BIN):
	tools/ferretdb/build.sh $(FERRETDB_BIN)

ferretdb: $(FERRETDB_BIN)

demo: $(STAMP) $(WEB_STAMP)
	$(PY) -m server.demo

# The suite runs on as many workers as the machine has cores, at most four, a test file
# each at a time (its module fixtures built once): most of its time is spent waiting on
# servers, agents and the browser. TEST_WORKERS=0 runs it in this one process.
TEST_WORKERS ?= auto
test: $(STAMP) $(FERRETDB_BIN) $(WEB_STAMP)
	FLEET_FERRETDB_BIN=$(abspath $(FERRETDB_BIN)) $(PY) -m pytest -q \
	  -n $(TEST_WORKERS) --maxprocesses=4 --dist loadfile $(PYTEST_ARGS)

lint: $(STAMP)
	$(VENV)/bin/ruff check .
	$(VENV)/bin/ruff format --check .
	$(VENV)/bin/mypy

bench: $(STAMP) $(FERRETDB_BIN)
	FLEET_FERRETDB_BIN=$(abspath $(FERRETDB_BIN)) $(PY) -m bench $(BENCH_ARGS)

# 1,000 vehicles at 1 Hz for 10 minutes with a short retention (RSS growth after the
# warm-up < 10 %), then each bound of the contract flooded (bench/_soak.py); e.g.
# SOAK_ARGS="--minutes 3" for a trial, "--runs 3" for min / median / max.
soak: $(STAMP)
	$(PY) -m bench._soak $(SOAK_ARGS)

# The fault runs at full size (tests/chaos: 50 agents, ten minutes of a bad link, ...),
# CHAOS_RUNS times, then their figures as min / median / max.
CHAOS_RUNS ?= 3
CHAOS_FIGURES := .cache/chaos/figures.jsonl

chaos: $(STAMP) $(FERRETDB_BIN)
	mkdir -p $(dir $(CHAOS_FIGURES)) && rm -f $(CHAOS_FIGURES)
	for run in $$(seq $(CHAOS_RUNS)); do \
	  FLEET_CHAOS=full FLEET_CHAOS_FIGURES=$(abspath $(CHAOS_FIGURES)) \
	  FLEET_FERRETDB_BIN=$(abspath $(FERRETDB_BIN)) $(PY) -m pytest -q -p no:cacheprovider \
	    tests/chaos $(PYTEST_ARGS) || exit 1; \
	done
	$(PY) -m tests.chaos.table $(CHAOS_FIGURES)

clean:
	rm -rf $(VENV) .pytest_cache .mypy_cache .ruff_cache
