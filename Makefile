# Two entry points for a fresh machine: `make demo` and `make test`.
# Each creates .venv and installs motorid into it when needed.
PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed
EXTRAS ?= test,dask

.PHONY: demo test venv clean

$(STAMP): pyproject.toml
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[$(EXTRAS)]'
	touch $(STAMP)

venv: $(STAMP)

demo: $(STAMP)
	$(BIN)/motorid demo --out demo-output

test: $(STAMP)
	$(BIN)/python -m pytest -q

clean:
	rm -rf $(VENV) demo-output build *.egg-info .pytest_cache
	rm -rf hardware/firmware/build hardware/sim/build

# Firmware build and AVR emulation (issue 6): firmware, avr-sim, firmware-deps; `test` needs them.
include hardware/avr.mk
