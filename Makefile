# vts-hw: every target sets itself up on a fresh Debian machine (CI runs as root).
#   make demo   the main job on the simulated rig
#   make test   the whole test suite
#   make bench  the benchmarks (ratios measured in one run)
#   make docs   the documentation site, built into site/ (mkdocs.yml; .venv/bin/mkdocs serve to read it live)

PYTHON ?= python3
VENV   := .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed
# Debian packages the tests need (installed when missing, if we may)
# (the AVR toolchain and simavr are installed by firmware/Makefile, which `make test` runs)
# (postgresql: the tests start a throwaway server of their own, tests/pgserver.py)
# (chromium and firefox-esr: the console's pages in both browsers)
# (avrdude: vts trigger flash uploads through the bootloader; tests/interop/test_trigger_flash.py to a simulated board)
TEST_DEBS := curl openssl chromium firefox-esr fonts-dejavu-core poppler-utils postgresql avrdude
# (wapiti: bench/web_scan.py, a web scanner written by others against the console)
BENCH_DEBS := wapiti

.PHONY: demo test bench docs venv debs firmware clean

venv: $(STAMP)

$(STAMP): pyproject.toml setup.py
	@tools/ensure-debs python3-venv
	@test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e '.[dev]'
	@touch $(STAMP)

debs:
	@tools/ensure-debs $(TEST_DEBS)

demo: $(STAMP)
	$(VENV)/bin/vts demo

# two pytest-xdist workers, a test module to one worker (its module fixtures made once; make test
# PYTEST_WORKERS=0 for one process); the real QATrack+'s tests are one module, run last, against
# the server the controller starts (tests/conftest.py)
PYTEST_WORKERS ?= 2

test: $(STAMP) debs
	$(MAKE) -C firmware
	$(PY) -m pytest $(if $(filter-out 0,$(PYTEST_WORKERS)),-n $(PYTEST_WORKERS) --dist loadscope)

bench: $(STAMP) debs
	@tools/ensure-debs $(BENCH_DEBS)
	$(MAKE) -C firmware
	$(PY) bench/run_all.py

# the documentation site: --strict, so a broken link or a missing page stops it (as in make test)
docs: $(STAMP)
	NO_MKDOCS_2_WARNING=1 $(VENV)/bin/mkdocs build --strict --site-dir site

# the trigger box firmware (avr-gcc) and its emulator harness (libsimavr)
firmware:
	$(MAKE) -C firmware

clean:
	rm -rf $(VENV) build *.egg-info .pytest_cache .hypothesis site
