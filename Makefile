# Two commands set everything up on a fresh machine:
#   make demo   -- create .venv, install, run the main job on the built-in asset
#   make test   -- create .venv, install, run the test suite (what .ci/run calls)
VENV ?= .venv
PY := $(VENV)/bin/python
# glibc returns and re-maps large buffers between training steps; these keep CPU steps steady.
export MALLOC_MMAP_THRESHOLD_ := 2000000000
export MALLOC_TRIM_THRESHOLD_ := 20000000000

.PHONY: setup test demo lint bench clean

setup: $(VENV)/.installed

$(VENV)/.installed: pyproject.toml
	python3 -m venv $(VENV)
	$(PY) -m pip install -q --disable-pip-version-check torch==2.13.0
	$(PY) -m pip install -q --disable-pip-version-check -e '.[dev,app]'
	touch $@

test: setup
	$(PY) -m ruff check geoscaler tests benchmarks
	$(PY) -m pytest -q

demo: setup
	$(VENV)/bin/geoscaler demo

bench: setup
	$(PY) benchmarks/bench_renderer.py

clean:
	rm -rf $(VENV) *.egg-info .pytest_cache .ruff_cache
