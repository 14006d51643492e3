# The two commands of the README: `make demo` (environment + demo) and `make test` (environment, linter, documentation
# and test suite). `make docs` builds the documentation alone.
PYTHON ?= python3
VENV ?= .venv
BIN := $(VENV)/bin
APT_PACKAGES := chromium
# The suite in two processes of one torch thread each (pytest-xdist; a file's tests stay in one process, so its
# module fixtures are made once): nearly every test trains or renders on one thread, which left a core idle.
PYTEST_WORKERS ?= -n 2 --dist loadfile
DEMO_APT_PACKAGES := libusb-1.0-0 ffmpeg

.PHONY: demo test docs env system demo-system

env: $(VENV)/.installed

# nerfstudio pulls opencv-python-headless; the contrib build (same version) is reinstalled last so that `cv2` is it.
# --no-compile: no .pyc for the ~5 GB of torch and CUDA wheels up front (about a minute of `make demo` on 2 cores);
# Python writes them for the modules it imports.
$(VENV)/.installed: pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/pip install --no-compile -e .
	$(BIN)/pip install --no-compile --force-reinstall --no-deps opencv-contrib-python-headless==4.10.0.84
	touch $@

# Debian packages the tests use: chromium (the viewer checked in a browser).
system:
	@if command -v chromium >/dev/null; then exit 0; fi; \
	if [ "$$(id -u)" = 0 ]; then SUDO=; else SUDO=sudo; fi; \
	echo "installing $(APT_PACKAGES) with apt-get"; \
	$$SUDO apt-get update -qq && DEBIAN_FRONTEND=noninteractive $$SUDO apt-get install -y -qq --no-install-recommends $(APT_PACKAGES)

# Debian packages the documented commands need at run time: libusb, which open3d loads (nerfstudio's ns-export and
# ssnerf-export-points import open3d), and ffmpeg, which ns-render's videos are written with.
demo-system:
	@if dpkg -s $(DEMO_APT_PACKAGES) >/dev/null 2>&1; then exit 0; fi; \
	if [ "$$(id -u)" = 0 ]; then SUDO=; else SUDO=sudo; fi; \
	echo "installing $(DEMO_APT_PACKAGES) with apt-get"; \
	$$SUDO apt-get update -qq && DEBIAN_FRONTEND=noninteractive $$SUDO apt-get install -y -qq --no-install-recommends $(DEMO_APT_PACKAGES)

demo: env demo-system
	$(BIN)/ssnerf-demo --output-dir demo_output --overwrite

# The test extras (pytest, ruff), the cluster extra (Ray), so that the tests cover `--launcher ray`, and the docs extra
# (Sphinx), which the tests build too.
$(VENV)/.test-extras: $(VENV)/.installed
	$(BIN)/pip install -e '.[cluster,test,docs]'
	touch $@ $(VENV)/.docs-extras

$(VENV)/.docs-extras: $(VENV)/.installed
	$(BIN)/pip install -e '.[docs]'
	touch $@

# The documentation (docs/, MyST Markdown) as HTML in docs/_build/html; any warning fails it.
docs: $(VENV)/.docs-extras
	$(BIN)/sphinx-build -W --keep-going -q -b html docs docs/_build/html

test: env demo-system system $(VENV)/.test-extras
	$(BIN)/ruff check ssnerf_method tests scripts benchmarks conftest.py
	$(MAKE) docs
	OMP_NUM_THREADS=1 $(BIN)/python -m pytest -q $(PYTEST_WORKERS)
