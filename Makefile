# `make demo` renders the example scene (16 samples a pixel: smooth edges), `make test` runs the tests; both first run
# scripts/setup.sh, which installs whatever is missing and is quick when nothing is.
PYTHON_VENV := .venv/bin/python
# Written by scripts/setup_intel_opencl.sh (opt-in; CI runs it): the system's OpenCL drivers plus
# Intel's CPU runtime. Only the tests use it, so `make demo` keeps the system's default device.
ICD_VENDORS := $(CURDIR)/.venv/opencl-vendors

.PHONY: setup demo test lint

setup:
	@bash scripts/setup.sh

demo: setup
	$(PYTHON_VENV) -m clray render scenes/spheres.toml --spp 16 -o spheres.png

test: setup
	@if [ -d "$(ICD_VENDORS)" ] && [ -z "$${OCL_ICD_VENDORS:-}" ]; then \
	    export OCL_ICD_VENDORS="$(ICD_VENDORS)"; \
	    echo "OCL_ICD_VENDORS=$$OCL_ICD_VENDORS"; \
	fi; \
	echo "$(PYTHON_VENV) -m pytest -q"; \
	$(PYTHON_VENV) -m pytest -q

lint: setup
	.venv/bin/ruff check clray tests benchmarks
