# Two entry points for a fresh machine: `make demo` and `make test`.
# Each creates .venv and installs motorid into it when needed; `make test` also builds the
# firmware and its AVR emulator (installing the Debian packages they need, see hardware/avr.mk).
# For development (docs/develop.md): `make test-fast` (no slow or firmware tests) and `make lint`.
PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed
EXTRAS ?= test,dask,lint,fast

.PHONY: demo test test-fast lint venv clean

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

# ruff and mypy, configured in pyproject.toml; any finding fails.
lint: $(STAMP)
	$(BIN)/ruff check .
	$(BIN)/mypy

clean:
	rm -rf $(VENV) demo-output build *.egg-info .pytest_cache .mypy_cache .ruff_cache .hypothesis
	rm -rf hardware/firmware/build hardware/sim/build

# Firmware build and AVR emulation: firmware, avr-sim, firmware-deps; `test` needs them.
include hardware/avr.mk
