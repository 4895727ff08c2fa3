# Every target sets up .venv itself: on a fresh clone `make lab` and `make test` are all you need.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
# System packages, installed with apt where missing: libgl1 and libegl1 for pyvista's headless
# rendering (EGL), chromium for the browser tests (tests/test_browser.py), bubblewrap for the
# grader's sandbox (src/diffnurbs_course/_sandbox.py).
export VTK_DEFAULT_OPENGL_WINDOW ?= vtkEGLRenderWindow
export PYVISTA_OFF_SCREEN ?= true

.PHONY: install lab test bench html exercises lint clean system-libs widgets

install: $(STAMP) system-libs

$(STAMP): pyproject.toml
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e ".[course,dev,cad]"
	touch $(STAMP)

system-libs:
	@missing=""; \
	ldconfig -p | grep -q 'libEGL.so.1' || missing="$$missing libegl1"; \
	ldconfig -p | grep -q 'libGL.so.1' || missing="$$missing libgl1"; \
	command -v chromium >/dev/null || missing="$$missing chromium"; \
	command -v bwrap >/dev/null || missing="$$missing bubblewrap"; \
	if [ -z "$$missing" ]; then :; \
	elif command -v apt-get >/dev/null && [ "$$(id -u)" = 0 ]; then \
		apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq $$missing; \
	else echo "warning: install$$missing (apt): pyvista's 3D figures and the browser tests need them"; fi

lab: install
	PYVISTA_OFF_SCREEN=false $(BIN)/jupyter lab --ServerApp.root_dir=. \
		--ServerApp.kernel_websocket_connection_class=diffnurbs_course.lab.NoDelayConnection \
		$$([ "$$(id -u)" = 0 ] && echo --allow-root) course/00_index.ipynb

test: install
	$(BIN)/ruff check src tests bench
	$(BIN)/python -m pytest -n 2 --dist worksteal --durations=15

bench: install
	$(BIN)/python bench/run.py

# Executes every chapter headless and builds the course website: build/site/_build/html/index.html.
html: install
	$(BIN)/python tools/build_html.py --out build/site

# Student notebooks exercises/NN_topic.ipynb from the masters solutions/NN_topic.ipynb (committed);
# otter's autograder versions, with the hidden tests, stay in build/otter/ (git-ignored).
exercises: install
	$(BIN)/python tools/make_exercises.py --solutions solutions --exercises exercises --build build/otter
	$(BIN)/python tools/make_exercises.py --solutions tests/data/solutions --exercises tests/data/exercises --build build/otter

# The 3D view's front end, bundled with three.js (needs Node; the bundle is committed, so
# `make install` does not). Its first line records the source's hash, which a test checks.
WIDGETS := tools/widgets
widgets:
	cd $(WIDGETS) && npm ci --silent
	hash=$$(sha256sum $(WIDGETS)/surface_view.js | cut -d' ' -f1); \
	$(WIDGETS)/node_modules/.bin/esbuild $(WIDGETS)/surface_view.js --bundle --format=esm \
		--minify --legal-comments=eof --outfile=src/diffnurbs/_static/surface_view.js \
		--banner:js="// Bundled by make widgets from tools/widgets/surface_view.js (sha256 $$hash) with three.js (MIT)."

lint: install
	$(BIN)/ruff check src tests bench
	$(BIN)/ruff format --check src tests bench

clean:
	rm -rf $(VENV) build .pytest_cache .ruff_cache
