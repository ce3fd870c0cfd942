# Two commands set everything up on a fresh machine:
#   make demo   -- create .venv, install, run the main job on the built-in asset
#   make test   -- create .venv, install, run the test suite (what .ci/run calls)
VENV ?= .venv
PY := $(VENV)/bin/python
# glibc returns and re-maps large buffers between training steps; these keep CPU steps steady.
export MALLOC_MMAP_THRESHOLD_ := 2000000000
export MALLOC_TRIM_THRESHOLD_ := 20000000000

.PHONY: setup system-packages validator test demo lint bench bench-app screenshot clean

# The app's tests need EGL (headless OpenGL, Mesa llvmpipe without a GPU) and Xvfb. `make test`
# installs them when missing and it runs as root (CI); otherwise it says so and those tests skip.
GL_PACKAGES := libegl1 libgl1 xvfb xauth
XVFB := xvfb-run -a -s "-screen 0 1600x1000x24"

setup: $(VENV)/.installed

$(VENV)/.installed: pyproject.toml setup.py
	python3 -m venv $(VENV)
	$(PY) -m pip install -q --disable-pip-version-check torch==2.13.0
	$(PY) -m pip install -q --disable-pip-version-check -e '.[dev,app]'
	touch $@

system-packages:
	@missing=""; for p in $(GL_PACKAGES); do dpkg -s $$p >/dev/null 2>&1 || missing="$$missing $$p"; done; \
	if [ -z "$$missing" ]; then exit 0; fi; \
	if [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null; then \
	  echo "installing$$missing for the app's tests"; \
	  (apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq $$missing \
	    >/dev/null) || echo "warning: could not install$$missing"; \
	else echo "note: missing$$missing (not root): the app's GL and GUI tests will skip"; fi

# The Khronos glTF-Validator (npm), pinned, for tests/test_gltf_validator.py: installed into
# .tools/ (ignored by git) only when missing. Without npm the test says so and fails, without
# node it skips.
GLTF_VALIDATOR_VERSION := 2.0.0-dev.3.10
TOOLS := .tools
VALIDATOR := $(TOOLS)/node_modules/gltf-validator/package.json

validator: $(VALIDATOR)

$(VALIDATOR):
	@if command -v npm >/dev/null; then \
	  echo "installing gltf-validator@$(GLTF_VALIDATOR_VERSION) into $(TOOLS)/"; \
	  npm install --prefix $(TOOLS) --no-save --no-audit --no-fund --loglevel=error \
	    gltf-validator@$(GLTF_VALIDATOR_VERSION) >/dev/null \
	    || echo "warning: could not install gltf-validator"; \
	else echo "note: npm is missing: the glTF-Validator test cannot run"; fi

# Under xvfb-run the app's tests must run: GEOSCALER_REQUIRE_GL=1 turns their skips into failures.
test: setup system-packages validator
	$(PY) -m ruff check geoscaler app tests benchmarks setup.py
	if command -v xvfb-run >/dev/null; then \
	  GEOSCALER_REQUIRE_GL=1 $(XVFB) $(PY) -m pytest -q; \
	else $(PY) -m pytest -q; fi

demo: setup
	$(VENV)/bin/geoscaler demo

bench: setup
	$(PY) benchmarks/bench_renderer.py

# Frames per second of the app while it trains (README figure).
bench-app: setup system-packages
	$(XVFB) $(PY) benchmarks/bench_app.py

# Re-make docs/results/*.json and docs/results.md: bicubic, Lanczos, direct and direct --uv auto on
# every development mesh at 4x and 8x, 60 s a learned job, scored on Q, near and far (1.5 to 2
# hours on 2 cores). Run it on an idle machine and say so: make results RESULTS_FLAGS=--alone;
# RESULTS_FLAGS=--render-only re-renders the page from the JSON files alone.
.PHONY: results
results: setup
	$(PY) benchmarks/results.py $(RESULTS_FLAGS)

# Re-make docs/app.png, the README's screenshot, with the GUI test.
screenshot: setup system-packages
	GEOSCALER_UPDATE_SCREENSHOT=1 $(XVFB) $(PY) -m pytest -q tests/test_app_gui.py

clean:
	rm -rf $(VENV) $(TOOLS) *.egg-info .pytest_cache .ruff_cache
