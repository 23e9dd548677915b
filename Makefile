# camcal: `make run` starts the system, `make test` runs every test.
# Both create .venv and install what they need on a fresh machine (camcal with every extra).
# `make test-core` installs what a module installs (`pip install camcal`, no extra) in a venv of
# its own and runs the module side's tests there.
PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed
DATA   ?= camcal-data
PORT   ?= 8000
INGEST_PORT ?= 5555
EVENTS_PORT ?= 5556

CORE   := .venv-core

.PHONY: run test test-core test-browser fuzz lint bench bench-dashboard demo clean

$(STAMP): pyproject.toml
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	# The camera extra (PyGObject, for Aravis) builds against the system's GObject introspection:
	# with Debian's libgirepository1.0-dev, libcairo2-dev and pkg-config (.ci/run installs them) it
	# comes along; without them it is left out, said here, and the camera tests skip saying why.
	extras=all,test; \
	if pkg-config --exists gobject-introspection-1.0 cairo 2>/dev/null; then extras=$$extras,camera; \
	else echo "camcal: no libgirepository1.0-dev/libcairo2-dev: the camera extra is left out (its tests skip)"; fi; \
	$(BIN)/python -m pip install --quiet -e ".[$$extras]"
	touch $(STAMP)

# Every port camcal up listens on is a variable here; CAMCAL_PORT_VARIABLES tells it their names,
# so that a port in use is answered with the variable to change (`make run INGEST_PORT=5565`).
run: $(STAMP)
	CAMCAL_PORT_VARIABLES="--port=PORT --ingest-port=INGEST_PORT --events-port=EVENTS_PORT" \
	  $(BIN)/camcal up --data $(DATA) --port $(PORT) --ingest-port $(INGEST_PORT) --events-port $(EVENTS_PORT)

demo: $(STAMP)
	$(BIN)/camcal demo --out demo-output

test: $(STAMP)
	$(BIN)/ruff check .
	$(BIN)/lint-imports
	$(BIN)/deptry .
	$(BIN)/mypy
	# Three workers on the two cores for every test but those marked solo (half of the tests'
	# time is spent waiting on processes and sockets, not computing). Then the solo ones: the
	# browser tests on their shared `camcal up`, and beside them (their log printed after) the
	# paced dive and station, which use ~0.4 of a core; never two browser systems at once.
	# One shared dive (tests/utils/dive_store.py) is streamed once for all of them.
	cache=$$(mktemp -d) && export CAMCAL_TEST_CACHE=$$cache \
	  && $(BIN)/python -m pytest -n 3 --dist loadfile -m "not solo" \
	  && { $(BIN)/python -m pytest -m solo tests/live > $$cache/paced.log 2>&1 & paced=$$!; \
	       $(BIN)/python -m pytest -m solo tests/browser; browser=$$?; \
	       wait $$paced; rc=$$?; echo "--- the paced dive and station (tests/live, solo):"; \
	       cat $$cache/paced.log; [ $$browser -eq 0 ] && [ $$rc -eq 0 ]; }; \
	  rc=$$?; rm -rf $$cache; exit $$rc

# A module's install: the core alone (no extra), built and installed as `pip install camcal` would,
# in a fresh venv; then `camcal lrm --help` and the module side's tests (their sources from here).
test-core:
	rm -rf $(CORE)
	$(PYTHON) -m venv $(CORE)
	$(CORE)/bin/python -m pip install --quiet . pytest pytest-xdist hypothesis
	$(CORE)/bin/camcal lrm --help >/dev/null
	$(CORE)/bin/python -m pytest -n 2 --dist loadfile -p no:cacheprovider tests/lrm tests/sim tests/camcal \
		tests/test_wire.py tests/test_frameset.py tests/cli/test_startup.py

# The protocol fuzzer's slow lane: 10 000 generated messages against a real ingest (make test sends 800).
fuzz: $(STAMP)
	CAMCAL_FUZZ_MESSAGES=10000 $(BIN)/python -m pytest tests/live/test_fuzz_ingest.py -q -s

test-browser: $(STAMP)
	$(BIN)/python -m pytest -m browser tests/browser

lint: $(STAMP)
	$(BIN)/ruff check .
	$(BIN)/ruff format --check .

bench: $(STAMP)
	$(BIN)/python bench/bench_startup.py
	$(BIN)/python bench/bench_analysis.py
	$(BIN)/python bench/bench_detect.py
	$(BIN)/python bench/bench_ingest.py

bench-dashboard: $(STAMP)
	$(BIN)/python bench/bench_dashboard.py

clean:
	rm -rf $(VENV) $(CORE) demo-output .pytest_cache .ruff_cache
