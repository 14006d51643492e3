# The two commands of the README: `make demo` (environment + demo) and `make test` (environment + test suite).
PYTHON ?= python3
VENV ?= .venv
BIN := $(VENV)/bin

.PHONY: demo test env

env: $(VENV)/.installed

# nerfstudio pulls opencv-python-headless; the contrib build (same version) is reinstalled last so that `cv2` is it.
$(VENV)/.installed: pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/pip install -e .
	$(BIN)/pip install --force-reinstall --no-deps opencv-contrib-python-headless==4.10.0.84
	touch $@

demo: env
	$(BIN)/ssnerf-demo --output-dir demo_output --overwrite

test: env
	$(BIN)/python -m pytest -q
