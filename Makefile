# Two entry points for a fresh machine: `make demo` and `make test`.
# Each creates .venv and installs motorid into it when needed; `make test` also builds the
# firmware and its AVR emulator (installing the Debian packages they need, see hardware/avr.mk).
# For development (docs/develop.md): `make test-fast` (no slow or firmware tests), `make lint`,
# `make docs` (the documentation site in build/docs/html, warnings as errors) and `make bench-check`
# (the speed gate in a plain install).
PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed
EXTRAS ?= test,dask,lint,fast,docs,ros,wpilib

.PHONY: demo test test-fast test-realtime lint docs venv clean bench-check

# Reinstalled when the dependencies (pyproject.toml) or the extras (this file) change.
$(STAMP): pyproject.toml Makefile
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[$(EXTRAS)]'
	touch $(STAMP)

venv: $(STAMP)

demo: $(STAMP)
	$(BIN)/motorid demo --out demo-output

# The whole suite; hardware/avr.mk adds the firmware and the emulator as prerequisites.
test: $(STAMP)
	$(BIN)/python -m pytest -q

# Everything but the tests marked slow or firmware (pyproject.toml lists the markers).
test-fast: $(STAMP)
	$(BIN)/python -m pytest -q -m "not slow and not firmware"

# The tests that run the emulated rigs against the wall clock (marker realtime): they show the
# host keeping up with the firmware's real deadlines, so they need an idle machine; not in `test`.
test-realtime: $(STAMP)
	$(BIN)/python -m pytest -q -m realtime --realtime

# ruff and mypy, configured in pyproject.toml; any finding fails.
lint: $(STAMP)
	$(BIN)/ruff check .
	$(BIN)/mypy

# The documentation site, built from scratch: every page, example and command output re-run;
# any warning fails the build.
docs: $(STAMP)
	rm -rf build/docs docs/auto_examples docs/reference/generated docs/_figures docs/sg_execution_times.rst
	MPLBACKEND=Agg $(BIN)/python -m sphinx -b html -W --keep-going -q docs build/docs/html
	@echo "docs: build/docs/html/index.html"

# The speed gate in the install a user makes: a new virtual environment with `pip install .` (numba comes
# with it) and the benchmarks' baseline (the `bench` extra: pandas, which motorid itself never imports), then
# `motorid bench --check` from inside that environment's folder, so the installed package is the one measured.
PLAIN := build/plain-venv
bench-check:
	rm -rf $(PLAIN)
	$(PYTHON) -m venv $(PLAIN)
	$(PLAIN)/bin/python -m pip install --quiet --upgrade pip
	$(PLAIN)/bin/python -m pip install --quiet '.[bench]'
	cd $(PLAIN) && bin/motorid bench --check

clean:
	rm -rf $(VENV) demo-output build docs/auto_examples docs/reference/generated docs/_figures *.egg-info .pytest_cache .mypy_cache .ruff_cache .hypothesis
	rm -rf hardware/firmware/build hardware/sim/build

# Firmware build and AVR emulation: firmware, avr-sim, firmware-deps; `test` needs them.
include hardware/avr.mk
