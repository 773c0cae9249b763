# carapost developer commands. `make demo` and `make test` work on a fresh machine.
PYTHON ?= python3
VENV := .venv
VPY := $(VENV)/bin/python
# the demo needs the package alone; tests and lint need the test extra too (the extra is
# most of the venv's size: pytest, hypothesis, the independent C3D/FBX readers, ruff)
STAMP := $(VENV)/.installed
TEST_STAMP := $(VENV)/.installed-test

.PHONY: demo test lint bench screenshots clean

$(VPY):
	$(PYTHON) -m venv $(VENV)
	$(VPY) -m pip install --upgrade pip

$(STAMP): $(VPY) pyproject.toml
	$(VPY) -m pip install -e .
	touch $(STAMP)

$(TEST_STAMP): $(STAMP)
	$(VPY) -m pip install -e '.[test]'
	touch $(TEST_STAMP)

demo: $(STAMP)
	$(VENV)/bin/carapost demo

# lint-imports checks the [tool.importlinter] contracts of pyproject.toml; pytest also
# runs the doctests of algorithms, io and model (testpaths).
test: $(TEST_STAMP)
	$(VENV)/bin/lint-imports
	QT_QPA_PLATFORM=offscreen $(VPY) -m pytest -q

lint: $(TEST_STAMP)
	$(VENV)/bin/ruff check src tests benchmarks examples

screenshots: $(TEST_STAMP)
	xvfb-run -a -s "-screen 0 1920x1080x24" $(VPY) -m carapost.ui.screenshots docs/screenshots

clean:
	rm -rf $(VENV) build *.egg-info src/*.egg-info
