# Two entry points: `make demo` (the main job) and `make test` (the suite).
# Each does its own idempotent set-up: Debian's libllvm19 for Mitsuba's LLVM
# variant, a virtual environment, and this package with its dependencies.

PYTHON ?= python3
VENV   ?= .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed

.PHONY: demo test test-fast test-other-cpu setup llvm lint clean chromium

demo: setup
	$(PY) -m sparse_brdf.demo

# The whole suite, then its numerics tests again on another CPU's kernels (docs/testing.md).
test: setup
	$(VENV)/bin/ruff check sparse_brdf mitsuba_plugin tests benchmarks examples
	$(PY) -m pytest -q --durations=10 tests
	$(MAKE) --no-print-directory test-other-cpu

# What neither renders, trains nor runs a bench: the edit-test loop.
test-fast: setup
	$(PY) -m pytest -q -m "not render and not train and not bench" tests

# numpy, OpenBLAS and Dr.Jit on kernels other than the ones they pick here
# (tests/other_cpu.py prints the settings).
test-other-cpu: setup
	env $$($(PY) tests/other_cpu.py) $(PY) -m pytest -q -m numerics tests

setup: llvm $(STAMP)

# Mitsuba's LLVM backend aborts with the stock libLLVM 15 ("Cannot select ... fminimum");
# Dr.Jit picks the newest libLLVM*.so it finds, so installing libllvm19 is enough.
llvm:
	@if ! ls /usr/lib/*-linux-gnu/libLLVM-19.so* /usr/lib/*-linux-gnu/libLLVM.so.19* >/dev/null 2>&1; then \
		echo "installing Debian's libllvm19 (needed by Mitsuba's LLVM variant)"; \
		SUDO=$$( [ "$$(id -u)" = 0 ] || echo sudo ); \
		$$SUDO apt-get update -qq && DEBIAN_FRONTEND=noninteractive $$SUDO apt-get install -y -qq libllvm19 >/dev/null; \
	fi

$(STAMP): pyproject.toml
	@test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip 'setuptools>=68' wheel
	$(PY) -m pip install -q -e '.[test]'
	@# bytecode now, as a non-editable install would have it: with PYTHONDONTWRITEBYTECODE
	@# set, every command would otherwise compile the package again (0.3 s a command)
	$(PY) -m compileall -q sparse_brdf mitsuba_plugin
	@touch $(STAMP)

# Optional: Debian's Chromium, which tests/test_html_report.py drives headless to check the
# bench's HTML report (skipped without it). Not part of `make test`: a large download.
chromium:
	@if ! command -v chromium >/dev/null 2>&1; then \
		SUDO=$$( [ "$$(id -u)" = 0 ] || echo sudo ); \
		$$SUDO apt-get update -qq && DEBIAN_FRONTEND=noninteractive $$SUDO apt-get install -y -qq chromium >/dev/null; \
	fi

lint: setup
	$(VENV)/bin/ruff check sparse_brdf mitsuba_plugin tests benchmarks examples

clean:
	rm -rf $(VENV) build *.egg-info
