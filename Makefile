# Every target sets up .venv itself: on a fresh clone `make lab` and `make test` are all you need.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
# Headless VTK renders through EGL; pyvista needs these shared libraries at run time.
SYSTEM_LIBS := libgl1 libegl1
export VTK_DEFAULT_OPENGL_WINDOW ?= vtkEGLRenderWindow
export PYVISTA_OFF_SCREEN ?= true

.PHONY: install lab test bench html exercises lint clean system-libs

install: $(STAMP) system-libs

$(STAMP): pyproject.toml
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e ".[course,dev]"
	touch $(STAMP)

system-libs:
	@if ldconfig -p | grep -q 'libEGL.so.1' && ldconfig -p | grep -q 'libGL.so.1'; then :; \
	elif command -v apt-get >/dev/null && [ "$$(id -u)" = 0 ]; then \
		apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq $(SYSTEM_LIBS); \
	else echo "warning: install $(SYSTEM_LIBS) (apt) for pyvista's 3D figures"; fi

lab: install
	PYVISTA_OFF_SCREEN=false $(BIN)/jupyter lab --ServerApp.root_dir=. \
		$$([ "$$(id -u)" = 0 ] && echo --allow-root) course/00_index.ipynb

test: install
	$(BIN)/ruff check src tests bench
	$(BIN)/python -m pytest -n 2 --durations=15

bench: install
	$(BIN)/python bench/run.py

# Executes every course/*.ipynb headless; writes build/html/index.html and one page per chapter.
html: install
	$(BIN)/python tools/build_html.py --out build/html

# Student notebooks exercises/NN_topic.ipynb from the masters solutions/NN_topic.ipynb (committed);
# otter's autograder versions, with the hidden tests, stay in build/otter/ (git-ignored).
exercises: install
	$(BIN)/python tools/make_exercises.py --solutions solutions --exercises exercises --build build/otter
	$(BIN)/python tools/make_exercises.py --solutions tests/data/solutions --exercises tests/data/exercises --build build/otter

lint: install
	$(BIN)/ruff check src tests bench
	$(BIN)/ruff format --check src tests bench

clean:
	rm -rf $(VENV) build .pytest_cache .ruff_cache
