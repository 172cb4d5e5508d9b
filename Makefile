# Everything a fresh machine needs is installed by these targets: a virtual environment in .venv, the package and
# its test extras. `make run` starts the main program, `make test` runs lint and the whole suite.
PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed

.PHONY: run test test-serial lint format bench clean contract

# setup.py also builds the C hot path (asm_py/_speedups.c over the C runtime's framing; issue 31) in place; without a
# C compiler the package installs without it and asm_py.speedups logs that the pure-Python path runs.
SPEEDUPS := setup.py asm_py/_speedups.c firmware/src/wire.c firmware/src/can.c $(wildcard firmware/include/asm/*.h)
$(STAMP): pyproject.toml $(SPEEDUPS)
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e '.[test,bench]'
	touch $(STAMP)

run: $(STAMP)
	$(VENV)/bin/asm-studio $(ARGS)

# The browser tests drive Debian's Chromium (never a browser downloaded by a tool).
CHROMIUM := /usr/bin/chromium
$(CHROMIUM):
	if [ "$$(id -u)" = 0 ]; then apt-get update && apt-get install -y chromium; \
	else sudo apt-get update && sudo apt-get install -y chromium; fi

# The C runtime's Cortex-M4 build (tests/firmware/test_firmware.py, bench/firmware.py): Debian's bare-metal toolchain.
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
	$(PY) -m basedpyright --level error

format: $(STAMP)
	$(PY) -m ruff format .
	$(PY) -m ruff check --fix .

# Three workers (pytest-xdist) on two cores: the browser tests are one xdist group (tests/studio/browser.py), run by
# one worker from the start while the two others run the rest (the suite waits on processes and simulated robots more
# than it computes: 484 s against two workers' 620-670 s at stop 49, docs/benchmarks.md, "The suite's time"). Four
# workers, the browser tests then in two groups, took 429-521 s, but of nine four-worker runs at stop 46 two passed;
# the seven others each failed one to three tests judged against the wall clock under that load, seven different ones
# (docs/benchmarks.md, "Four workers, two browser groups"). TEST_WORKERS=N to change; `make test-serial` runs the
# same tests in one process.
TEST_WORKERS ?= 3
PYTEST := PLAYWRIGHT_SKIP_BROWSER_DOWNLOAD=1 $(PY) -m pytest
# The `realtime` tests (judged on the wall clock while a simulation runs in real time) failed beside four workers'
# load, so with four or more they run after the rest, three at a time; fewer workers run them with the rest, as a
# separate part cost 62 s there (stop 46's landing run) and they passed inside it before (stop 45).
# (TEST_WORKERS may be `auto` or `logical`, as for pytest-xdist: here one worker per core this process may run on. In
# two parts, one may select nothing — pytest's exit status 5 — while the other runs tests; nothing selected in both,
# or in the one part of fewer workers, fails.)
test: lint $(CHROMIUM) $(ARM_GCC)
	workers='$(TEST_WORKERS)'; \
	case "$$workers" in auto|logical) workers=$$($(PY) -c 'import os; print(len(os.sched_getaffinity(0)))');; esac; \
	if [ "$$workers" -ge 4 ]; then \
	  $(PYTEST) -m "not slow and not realtime" -n $$workers --dist loadgroup $(PYTEST_ARGS); first=$$?; \
	  if [ $$first -ne 0 ] && [ $$first -ne 5 ]; then exit $$first; fi; \
	  $(PYTEST) -m "realtime and not slow" -n 3 $(PYTEST_ARGS); second=$$?; \
	  if [ $$second -ne 0 ] && [ $$second -ne 5 ]; then exit $$second; fi; \
	  if [ $$first -eq 5 ] && [ $$second -eq 5 ]; then echo "no test selected"; exit 5; fi; \
	else \
	  $(PYTEST) -m "not slow" -n $$workers --dist loadgroup $(PYTEST_ARGS); \
	fi

test-serial: lint $(CHROMIUM) $(ARM_GCC)
	$(PYTEST) -m "not slow" $(PYTEST_ARGS)

# Every bench but the suite's own timing (bench/make_test.py runs `make test`).
bench: $(STAMP) $(ARM_GCC)
	for script in $(filter-out bench/make_test.py,$(wildcard bench/*.py)); do $(PY) $$script || exit 1; done

clean:
	rm -rf $(VENV) build *.egg-info .pytest_cache .ruff_cache asm_py/*.so
