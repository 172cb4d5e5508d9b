# Everything a fresh machine needs is installed by these targets: a virtual environment in .venv, the package and
# its test extras. `make run` starts the main program, `make test` runs lint and the whole suite.
PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed

.PHONY: run test lint format bench clean contract

$(STAMP): pyproject.toml
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e '.[test]'
	touch $(STAMP)

run: $(STAMP)
	$(VENV)/bin/asm-studio $(ARGS)

# The browser tests drive Debian's Chromium (never a browser downloaded by a tool).
CHROMIUM := /usr/bin/chromium
$(CHROMIUM):
	if [ "$$(id -u)" = 0 ]; then apt-get update && apt-get install -y chromium; \
	else sudo apt-get update && sudo apt-get install -y chromium; fi

# The C runtime's Cortex-M4 build (tests/test_firmware.py, bench/firmware.py): Debian's bare-metal toolchain.
ARM_GCC := /usr/bin/arm-none-eabi-gcc
$(ARM_GCC):
	if [ "$$(id -u)" = 0 ]; then apt-get update && apt-get install -y gcc-arm-none-eabi libnewlib-arm-none-eabi; \
	else sudo apt-get update && sudo apt-get install -y gcc-arm-none-eabi libnewlib-arm-none-eabi; fi

# The wire contract (contract/*.toml) generates asm_py/_contract.py, asm_module/_profile.py, the C headers and the
# tables of docs/protocol.md; the test suite fails when one of them is stale.
contract: $(STAMP)
	$(PY) contract/generate.py

lint: $(STAMP)
	$(PY) -m ruff check .
	$(PY) -m ruff format --check .

format: $(STAMP)
	$(PY) -m ruff format .
	$(PY) -m ruff check --fix .

test: lint $(CHROMIUM) $(ARM_GCC)
	PLAYWRIGHT_SKIP_BROWSER_DOWNLOAD=1 $(PY) -m pytest -m "not slow"

bench: $(STAMP) $(ARM_GCC)
	for script in bench/*.py; do $(PY) $$script || exit 1; done

clean:
	rm -rf $(VENV) build *.egg-info .pytest_cache .ruff_cache
