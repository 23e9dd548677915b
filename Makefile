# camcal: `make run` starts the system, `make test` runs every test.
# Both create .venv and install what they need on a fresh machine.
PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed
DATA   ?= camcal-data
PORT   ?= 8000

.PHONY: run test test-browser fuzz lint bench bench-dashboard demo clean

$(STAMP): pyproject.toml
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[test]'
	touch $(STAMP)

run: $(STAMP)
	$(BIN)/camcal up --data $(DATA) --port $(PORT)

demo: $(STAMP)
	$(BIN)/camcal demo --out demo-output

test: $(STAMP)
	$(BIN)/ruff check .
	$(BIN)/lint-imports
	$(BIN)/mypy
	$(BIN)/python -m pytest -n 2 --dist loadgroup

# The protocol fuzzer's slow lane: 10 000 generated messages against a real ingest (make test sends 800).
fuzz: $(STAMP)
	CAMCAL_FUZZ_MESSAGES=10000 $(BIN)/python -m pytest tests/live/test_fuzz_ingest.py -q -s

test-browser: $(STAMP)
	$(BIN)/python -m pytest -m browser tests/browser

lint: $(STAMP)
	$(BIN)/ruff check .
	$(BIN)/ruff format --check .

bench: $(STAMP)
	$(BIN)/python bench/bench_analysis.py
	$(BIN)/python bench/bench_detect.py
	$(BIN)/python bench/bench_ingest.py

bench-dashboard: $(STAMP)
	$(BIN)/python bench/bench_dashboard.py

clean:
	rm -rf $(VENV) demo-output .pytest_cache .ruff_cache
