# `make demo` renders the example scene, `make test` runs the tests; both first run
# scripts/setup.sh, which installs whatever is missing and is quick when nothing is.
PYTHON_VENV := .venv/bin/python

.PHONY: setup demo test lint

setup:
	@bash scripts/setup.sh

demo: setup
	$(PYTHON_VENV) -m clray render scenes/spheres.toml -o spheres.png

test: setup
	$(PYTHON_VENV) -m pytest -q

lint: setup
	.venv/bin/ruff check clray tests
