# Two entry points for a fresh machine: `make run` and `make test`.
PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
STAMP_RUN := $(VENV)/.stamp-run
STAMP_TEST := $(VENV)/.stamp-test
STAMP_BENCH := $(VENV)/.stamp-bench

.PHONY: run test test-offscreen test-gl bench venv clean

$(PY):
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip

# After installing, compile the filter's kernels once (numba caches them on disk; about half a
# minute the first time) so the first window does not wait for the compiler.
WARM := @echo "compiling the filter kernels (first time only)..." && $(PY) -c "import app.engine.warmup as w; w.warm_up()"

$(STAMP_RUN): pyproject.toml | $(PY)
	$(PY) -m pip install -q -e '.[mat]'
	$(WARM)
	touch $@

$(STAMP_TEST): pyproject.toml | $(PY)
	$(PY) -m pip install -q -e '.[test,mat]'
	$(WARM)
	touch $@ $(STAMP_RUN)

$(STAMP_BENCH): pyproject.toml | $(PY)
	$(PY) -m pip install -q -e '.[test,mat,bench]'
	touch $@ $(STAMP_TEST) $(STAMP_RUN)

venv: $(STAMP_RUN)

run: $(STAMP_RUN)
	$(VENV)/bin/orientation-lab --demo

# The whole suite: offscreen first, then the GL tests under a virtual X server when one exists.
test: $(STAMP_TEST)
	QT_QPA_PLATFORM=offscreen $(PY) -m pytest -q -m "not gl"
	@if command -v xvfb-run >/dev/null 2>&1; then \
		env -u QT_QPA_PLATFORM xvfb-run -a -s "-screen 0 1600x1000x24" $(PY) -m pytest -q -m gl; \
	else echo "xvfb-run not found: GL tests skipped (install xvfb to run them)"; fi

bench: $(STAMP_BENCH)
	$(PY) benchmarks/accuracy.py
	$(PY) benchmarks/speed.py

clean:
	rm -rf $(VENV) .pytest_cache build *.egg-info
