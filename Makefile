# granbayes: `make demo` and `make test` bootstrap .venv from a bare python3.12.
SHELL := /bin/bash
VENV := .venv
BIN := $(VENV)/bin
# The first Python >= 3.12 found: python3.12 on PATH, then common install locations.
PYTHON ?= $(shell for p in python3.12 python3.13 $$HOME/.pyenv/versions/3.12*/bin/python3.12 \
	/usr/local/bin/python3.12 /usr/bin/python3.12; do \
	"$$p" -c 'import sys; sys.exit(sys.version_info < (3, 12))' >/dev/null 2>&1 && { echo "$$p"; break; }; done)

.PHONY: demo test test-slow lint format bench analyses clean

$(BIN)/.installed: pyproject.toml
	@test -n "$(PYTHON)" || { echo "error: Python >= 3.12 not found (set PYTHON=/path/to/python3.12)"; exit 1; }
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e ".[dev]"
	touch $@

demo: $(BIN)/.installed
	$(BIN)/granbayes demo --out demo-output

test: $(BIN)/.installed
	$(BIN)/ruff check granbayes tests benchmarks analyses data
	$(BIN)/ruff format --check granbayes tests benchmarks analyses data
	$(BIN)/python -m pytest -m "not slow" -n 2

test-slow: $(BIN)/.installed
	$(BIN)/python -m pytest -m slow -n 2 --dist loadgroup

lint: $(BIN)/.installed
	$(BIN)/ruff check granbayes tests benchmarks analyses data

format: $(BIN)/.installed
	$(BIN)/ruff format granbayes tests benchmarks analyses data
	$(BIN)/ruff check --fix granbayes tests benchmarks analyses data

bench: $(BIN)/.installed
	$(BIN)/python benchmarks/bench_simulator.py
	$(BIN)/python benchmarks/bench_fit.py
	$(BIN)/python benchmarks/bench_diagnose.py

# The analyses of analyses/ on an experiment folder (default: the SYNTHETIC reference data),
# written to $(ANALYSES_OUT)/<analysis>/. On the reference data the improved law is the one
# `granbayes diagnose` selects there (depth + drag + compaction; docs/analyses/README.md).
DATA ?= data/reference
ANALYSES_OUT ?= docs/analyses
IMPROVED_LAW ?= depth,drag,compaction
RUN_ANALYSIS = $(BIN)/python analyses/$@.py $(DATA) --out $(ANALYSES_OUT)/$@
ANALYSES := preload_transfer misfit_maps heights_vs_phi added_mass_impulse one_force_law \
	optimal_jumping hard_ground

.PHONY: $(ANALYSES)
analyses: $(ANALYSES)

preload_transfer misfit_maps heights_vs_phi added_mass_impulse hard_ground: $(BIN)/.installed
	$(RUN_ANALYSIS)

one_force_law: $(BIN)/.installed
	$(RUN_ANALYSIS) --terms depth,drag --terms $(IMPROVED_LAW)

optimal_jumping: $(BIN)/.installed
	$(RUN_ANALYSIS) --terms $(IMPROVED_LAW)

clean:
	rm -rf $(VENV) demo-output .pytest_cache
