# Two entry points for a new user (see README.md):
#   make demo   set everything up, simulate the paper scenario, calibrate it, print the accuracy table
#   make test   set everything up and run the test suite
PYTHON ?= python3
VENV   ?= .venv
BIN     = $(VENV)/bin
SUDO   := $(shell [ "$$(id -u)" = 0 ] || echo sudo)
OUT    ?= runs/paper

.PHONY: demo test setup system-deps bench clean

setup: $(VENV)/.installed

# open3d loads libusb-1.0 and LightGBM the OpenMP runtime (libgomp) at import time; install them
# through apt when they are missing.
system-deps:
	@missing=""; \
	ldconfig -p 2>/dev/null | grep -q 'libusb-1.0.so.0' || missing="$$missing libusb-1.0-0"; \
	ldconfig -p 2>/dev/null | grep -q 'libgomp.so.1' || missing="$$missing libgomp1"; \
	if [ -n "$$missing" ]; then \
		echo "installing$$missing (needed by open3d / LightGBM)"; \
		$(SUDO) apt-get update -qq && $(SUDO) apt-get install -y -qq $$missing; \
	fi

$(VENV)/.installed: pyproject.toml | system-deps
	$(PYTHON) -m venv $(VENV)
	$(BIN)/pip install --quiet --upgrade pip
	$(BIN)/pip install --quiet -e '.[dev]'
	touch $@

demo: setup
	$(BIN)/pedcal demo -o $(OUT)

# the suite on every core (at most TEST_WORKERS), each test file on one worker (its module's
# fixtures built once); `.venv/bin/python -m pytest FILE` runs a part in one process
TEST_WORKERS ?= 4
test: setup
	$(BIN)/python -m pytest -q -n auto --maxprocesses $(TEST_WORKERS) --dist loadfile

bench: setup
	@for b in benchmarks/bench_*.py; do echo "== $$b"; $(BIN)/python $$b || exit 1; done

clean:
	rm -rf $(VENV) runs build *.egg-info
