# Two commands for a fresh machine: `make demo` (set up, run the main job on the embedded
# sample world, validate its clips) and `make test` (set up, lint, run the tests).
PYTHON ?= python3
VENV ?= .venv
PY := $(VENV)/bin/python
OUT ?= out/demo

.PHONY: setup demo test bench

setup: $(VENV)/.installed

$(VENV)/.installed: pyproject.toml
	@# open3d needs the system library libusb-1.0 (and libgomp); install them when missing.
	@if ! ldconfig -p | grep -q 'libusb-1.0.so.0' || ! ldconfig -p | grep -q 'libgomp.so.1'; then \
	  if [ "$$(id -u)" = 0 ]; then apt-get update -qq && apt-get install -y -qq libusb-1.0-0 libgomp1 >/dev/null; \
	  else sudo apt-get update -qq && sudo apt-get install -y -qq libusb-1.0-0 libgomp1 >/dev/null; fi; \
	fi
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	$(PY) -m pip install -q -e ".[test]"
	touch $@

demo: setup
	$(PY) -m pipeline.run --source drivetrack --runner DirectRunner --output $(OUT)
	$(PY) -m pipeline.validate $(OUT)

test: setup
	$(PY) -m ruff check pipeline tests
	$(PY) -m pytest -q

bench: setup
	$(PY) -m pipeline.bench drivetrack
