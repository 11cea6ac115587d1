# `make demo` renders the example scene (16 samples a pixel: smooth edges), `make test` runs the tests; both first run
# scripts/setup.sh, which installs whatever is missing and is quick when nothing is.
PYTHON_VENV := .venv/bin/python
# Written by scripts/setup_intel_opencl.sh (opt-in; CI runs it): the system's OpenCL drivers plus
# Intel's CPU runtime. Only the tests use it, so `make demo` keeps the system's default device.
ICD_VENDORS := $(CURDIR)/.venv/opencl-vendors

.PHONY: setup demo test test-other-lanes test-opencl-ulps lint

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

# The tests whose builds follow the device's vector width (sample-packet lanes, BVH width), at the
# width this machine lacks: CI's machines are AVX2 (8 floats) or AVX-512 (16), and either kind
# checks both (tests/conftest.py, --lanes other).
LANE_TESTS := tests/test_tuning.py tests/test_packets.py tests/test_wide.py tests/test_render.py

test-other-lanes: setup
	@if [ -d "$(ICD_VENDORS)" ] && [ -z "$${OCL_ICD_VENDORS:-}" ]; then \
	    export OCL_ICD_VENDORS="$(ICD_VENDORS)"; \
	fi; \
	echo "$(PYTHON_VENV) -m pytest -q --lanes other $(LANE_TESTS)"; \
	$(PYTHON_VENV) -m pytest -q --lanes other $(LANE_TESTS)

# The tests that compare with an oracle, and those that hold a ray's image to its lane-wise
# twins' bit for bit, their kernels built as a GPU builds them (--gpu-build: a pixel a
# work-item) with the transcendental builtins off by OpenCL's whole error bounds, upwards and
# downwards, and the geometric builtins fused (tests/conftest.py, --opencl-ulps; kernels/real.h,
# MATH_ULPS_OFF), on PoCL: a GPU's builtins may be so where the CPU's are within an ulp and
# round every product.
ULPS_TESTS := tests/hard_cases tests/test_render.py tests/test_background.py tests/test_camera.py \
	tests/test_depth.py tests/test_torus.py tests/test_area_lights.py tests/test_fresnel.py \
	tests/test_reference.py tests/test_intersect.py tests/test_instances.py tests/test_packets.py

test-opencl-ulps: setup
	@if [ -d "$(ICD_VENDORS)" ] && [ -z "$${OCL_ICD_VENDORS:-}" ]; then \
	    export OCL_ICD_VENDORS="$(ICD_VENDORS)"; \
	fi; \
	for off in 1 -1; do \
	    echo "$(PYTHON_VENV) -m pytest -q --cl-device pocl --gpu-build --opencl-ulps=$$off $(ULPS_TESTS)"; \
	    $(PYTHON_VENV) -m pytest -q --cl-device pocl --gpu-build --opencl-ulps=$$off $(ULPS_TESTS) || exit 1; \
	done

lint: setup
	.venv/bin/ruff check clray tests benchmarks scripts
