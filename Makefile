# Every target installs what it needs on a fresh machine and is quick when already installed.
PY      ?= python3
VENV    := .venv
BIN     := $(VENV)/bin
STAMP   := $(VENV)/.stamp-install
EXT_STAMP := $(VENV)/.stamp-compiled
APT_STAMP := $(VENV)/.stamp-apt

.PHONY: demo test test-pure conformance bench soak soak-ethercat lint typecheck install apt clean

$(BIN)/python:
	$(PY) -m venv $(VENV)

# The example device plugin (docs/devices/writing-a-device.md) is installed too: tests and docs use it.
EXAMPLE_DEVICE := examples/gatewaylab-example-device
# Dependencies first, pure Python (quick); the compiled extensions come from $(EXT_STAMP) below.
$(STAMP): pyproject.toml setup.py $(EXAMPLE_DEVICE)/pyproject.toml | $(BIN)/python
	$(BIN)/python -m pip install --quiet --upgrade pip
	GATEWAYLAB_COMPILE=0 $(BIN)/python -m pip install --quiet -e '.[dev]'
	$(BIN)/python -m pip install --quiet --no-deps -e $(EXAMPLE_DEVICE)
	touch $@

# The modules of gatewaylab/build_info.py COMPILED_MODULES are compiled with mypyc in place (the
# editable install puts each .so beside its .py). Rebuilt whenever one of their sources is newer than
# the stamp: an edited module must never run as its stale .so. Old extensions are removed first, so a
# module taken off the list runs from source again. GATEWAYLAB_COMPILE=1: fail without a C compiler
# (CI); 0: pure Python only; auto (default): compiled when possible.
GATEWAYLAB_COMPILE ?= auto
COMPILED_SOURCES := $(shell $(PY) -c 'import runpy; print(*(m.replace(".", "/") + ".py" for m in runpy.run_path("gatewaylab/build_info.py")["COMPILED_MODULES"]))')
$(EXT_STAMP): $(STAMP) setup.py gatewaylab/build_info.py $(COMPILED_SOURCES)
	find gatewaylab -name '*.so' -delete
	rm -f gatewaylab__mypyc.*
	GATEWAYLAB_COMPILE=$(GATEWAYLAB_COMPILE) $(BIN)/python -m pip install --quiet --no-deps -e .
	$(BIN)/python -c 'from gatewaylab import build_info; print("gatewaylab:", build_info.summary())'
	touch $@

# Debian packages some tests need: iproute2 (veth pairs and namespaces of the EtherCAT wire tests)
# and tshark (Wireshark's EtherCAT dissector reads our captures), chromium (the esd web pages' browser
# tests drive it through Playwright; never `playwright install`). Installed once, as root.
APT_PACKAGES := iproute2:ip tshark:tshark chromium:chromium
$(APT_STAMP): Makefile | $(BIN)/python
	@missing=""; for pc in $(APT_PACKAGES); do command -v $${pc#*:} >/dev/null 2>&1 || missing="$$missing $${pc%%:*}"; done; \
	if [ -n "$$missing" ]; then \
	  if [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1; then \
	    echo "installing Debian packages:$$missing"; \
	    apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq $$missing >/dev/null; \
	  else echo "warning: missing$$missing and cannot install them; the tests that need them skip"; fi; \
	fi
	touch $@

install: $(STAMP) $(EXT_STAMP) $(APT_STAMP)

apt: $(APT_STAMP)

demo: install
	$(BIN)/python -m gatewaylab.cli.demo

# Two workers, one per core (whole files per worker: module fixtures such as the veth namespace stay in one).
test: install
	$(BIN)/python -m pytest -q -n 2 --dist loadfile

# The same suite with every module imported from its .py (the compiled extensions stay unused).
test-pure: install
	GATEWAYLAB_PURE=1 $(BIN)/python -m pytest -q -n 2 --dist loadfile

# python-can's and canopen's own test suites (the installed versions, sdists from the package index)
# against a rig, through the `gatewaylab` interface; skips only what conformance/inapplicable.toml lists.
conformance: install
	$(BIN)/python conformance/run.py

bench: install
	$(BIN)/python -m benchmarks

# The default rig under 2,000 frames/s from three clients + an SDO loop (not part of `make test`,
# which runs a 20 s version); SOAK_MINUTES=60 make soak for an hour.
SOAK_MINUTES ?= 10
soak: install
	$(BIN)/python -m benchmarks.soak --minutes $(SOAK_MINUTES)

# SOEM at 1 kHz (2 ms timeout, no retries) against a mixed EtherCAT segment with CAN load, through
# `gatewaylab run` on a veth pair (root); prints wrong working counters, late replies and dropped-late
# frames (docs/performance.md). Not part of `make test`; SOAK_MINUTES=60 make soak-ethercat for an hour,
# SOAK_LOAD=loaded adds a CPU-busy background process.
SOAK_LOAD ?= quiet
soak-ethercat: install
	$(BIN)/python -m benchmarks.soak_ethercat --minutes $(SOAK_MINUTES) --load $(SOAK_LOAD)

lint: install
	$(BIN)/ruff check gatewaylab tests benchmarks examples conformance setup.py
	$(BIN)/mypy

clean:
	rm -rf $(VENV) .pytest_cache .mypy_cache .ruff_cache build *.egg-info gatewaylab__mypyc.*
	find gatewaylab -name '*.so' -delete
