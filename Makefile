# Two commands for a fresh machine: `make demo` (set up, run the main job of every registered source
# on its sample as a release run, validate its clips, show its verdicts: pipeline/demo.py) and
# `make test` (set up, lint, run the tests).
PYTHON ?= python3
VENV ?= .venv
PY := $(VENV)/bin/python
OUT ?= out/demo
# The real ADT excerpt shipped beside the project (read in place, never copied); exported, so the
# demo, the tests and the benchmarks read the same one (pipeline.adt.sample.excerpt.excerpt_path reads it).
ADT_EXCERPT ?= ../shared/data/adt_sample/aria_digital_twin_test_data
export ADT_EXCERPT
# The samples' splits file (pipeline.runner.splits.SAMPLE_RELEASE): the demo is a release run of it, so
# its verdicts show clips written, not produced and input absent, each with its reason.
SAMPLE_RELEASE := pipeline/runner/sample_splits.json

.PHONY: setup demo test typecheck bench bench-full

setup: $(VENV)/.installed

$(VENV)/.installed: pyproject.toml
	@# open3d needs the system library libusb-1.0 (and libgomp); the audit page's tests need headless
	@# Chromium and its driver (/usr/bin/chromium, /usr/bin/chromedriver); install them when missing.
	@if ! ldconfig -p | grep -q 'libusb-1.0.so.0' || ! ldconfig -p | grep -q 'libgomp.so.1' \
	  || [ ! -x /usr/bin/chromium ] || [ ! -x /usr/bin/chromedriver ]; then \
	  PACKAGES="libusb-1.0-0 libgomp1 chromium chromium-driver"; \
	  if [ "$$(id -u)" = 0 ]; then apt-get update -qq && apt-get install -y -qq $$PACKAGES >/dev/null; \
	  else sudo apt-get update -qq && sudo apt-get install -y -qq $$PACKAGES >/dev/null; fi; \
	fi
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	$(PY) -m pip install -q -e ".[test]"
	touch $@

demo: setup
	$(PY) -m pipeline.demo --output $(OUT) --release $(SAMPLE_RELEASE)

# typecheck: mypy over pipeline/ alone (configured in pyproject.toml; make test runs it too).
typecheck: setup
	$(PY) -m mypy

# The suite on every core (at most 4 worker processes), one test file per worker so a file's
# module-scoped runs happen once; `$(PY) -m pytest tests/<file>` runs one file in this process.
# mypy runs beside the tests at a lower priority (on the time a core of theirs is idle), its report
# printed after theirs; either failing fails the target. The suite starts dozens of interpreters on
# the same sources: their bytecode is cached (__pycache__) even where PYTHONDONTWRITEBYTECODE is set.
test: setup
	$(PY) -m ruff check pipeline tests benchmarks
	@report=$$(mktemp); \
	echo "$(PY) -m mypy (beside the tests, at a lower priority; its report follows theirs)"; \
	nice -n 19 $(PY) -m mypy >$$report 2>&1 & checker=$$!; \
	PYTHONDONTWRITEBYTECODE= $(PY) -m pytest -q -n auto --maxprocesses=4 --dist loadfile --no-loadscope-reorder; tests=$$?; \
	wait $$checker; typed=$$?; cat $$report; rm -f $$report; \
	test $$tests = 0 && test $$typed = 0

# bench: a few minutes (inputs as large per frame as the release's, fewer frames; units extrapolated),
# one table at the end, also in out/bench/bench.json. bench-full: the full-size inputs (writing them
# takes about 7 minutes the first time) and every source's groups also through python -m pipeline.run
# on Beam (--beam), table in out/bench/bench-full.json.
bench: setup
	$(PY) -m benchmarks all

bench-full: setup
	$(PY) -m benchmarks all --full --beam
