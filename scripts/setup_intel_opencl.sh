#!/usr/bin/env bash
# Opt-in second OpenCL device for the tests (CI runs it): Intel's CPU runtime from PyPI into
# .venv, and an ICD vendors folder, .venv/opencl-vendors, listing it beside the drivers the system
# already has. `make test` points OCL_ICD_VENDORS at that folder when it exists. Run after
# scripts/setup.sh. Never fails its caller: where the runtime cannot be had or does not work,
# the folder is removed, one line says so, and the tests run on the other devices.
set -euo pipefail
cd "$(dirname "$0")/.."

venv_python=.venv/bin/python
vendors=.venv/opencl-vendors
log=.venv/intel-opencl-setup.log
# Pinned to the versions the suite was last checked against (docs/testing.md).
packages=(intel-opencl-rt==2026.2.0 intel-cmplr-lib-rt==2026.2.0)
intel_platform="Intel(R) OpenCL"

say() { echo "setup: $*" >&2; }
give_up() {
    rm -rf "$vendors" "$vendors.new"
    say "Intel CPU OpenCL runtime not set up ($1); testing on the other OpenCL devices only"
    exit 0
}

if [ ! -x "$venv_python" ]; then
    say "no .venv: run scripts/setup.sh first"
    exit 1
fi

: >"$log"

# Platform names, one a line, sorted, as the loader finds them under the current environment.
list_platforms='
import pyopencl as cl
try:
    names = [p.name.strip() for p in cl.get_platforms()]
except cl.Error:  # no platform at all
    names = []
print("\n".join(sorted(names)))'
before=$("$venv_python" -c "$list_platforms" 2>>"$log") || give_up "pyopencl does not load"
if grep -qxF "$intel_platform" <<<"$before"; then
    rm -rf "$vendors"
    say "Intel CPU OpenCL runtime already installed on this system; nothing to add"
    exit 0
fi

if ! "$venv_python" -m pip install --disable-pip-version-check "${packages[@]}" >>"$log" 2>&1; then
    give_up "pip install failed, see $log"
fi
# The wheels put the runtime in the venv's lib folder. It finds the libraries it needs beside
# itself (RUNPATH $ORIGIN), so no LD_LIBRARY_PATH: that would also hand PoCL and clinfo the
# wheel's own libhwloc and libOpenCL in place of the system's.
library="$(cd .venv/lib && pwd)/libintelocl.so"
[ -f "$library" ] || give_up "no libintelocl.so in .venv/lib after pip install"

# Setting OCL_ICD_VENDORS replaces the loader's default folder, so the system's drivers are
# listed again beside Intel's. The wheel's own .venv/etc/OpenCL/vendors/*.icd name a
# placeholder install prefix and do not load.
rm -rf "$vendors.new"
mkdir -p "$vendors.new"
for icd in "${OCL_ICD_VENDORS:-/etc/OpenCL/vendors}"/*.icd; do
    if [ -e "$icd" ]; then cp "$icd" "$vendors.new/"; fi
done
echo "$library" >"$vendors.new/intel-cpu.icd"

expected=$(printf '%s\n%s\n' "$before" "$intel_platform" | sed '/^$/d' | sort)
after=$(OCL_ICD_VENDORS="$PWD/$vendors.new" "$venv_python" -c "$list_platforms" 2>>"$log") || after=""
if [ "$after" != "$expected" ]; then
    give_up "with it the platforms are [${after//$'\n'/, }], expected [${expected//$'\n'/, }]"
fi
# A platform that lists is not yet one that compiles: build and run one kernel on it. Past
# pyopencl's binary cache: a lock that a killed process left there failed this check once.
if ! PYOPENCL_NO_CACHE=1 OCL_ICD_VENDORS="$PWD/$vendors.new" "$venv_python" -c '
import numpy as np
import pyopencl as cl
import sys
platform = next(p for p in cl.get_platforms() if p.name.strip() == sys.argv[1])
ctx = cl.Context(platform.get_devices())
queue = cl.CommandQueue(ctx)
out = cl.Buffer(ctx, cl.mem_flags.WRITE_ONLY, 4 * 4)
cl.Program(ctx, "__kernel void k(__global int* o) { o[get_global_id(0)] = 7; }").build().k(
    queue, (4,), None, out)
got = np.zeros(4, np.int32)
cl.enqueue_copy(queue, got, out)
sys.exit(0 if (got == 7).all() else 1)' "$intel_platform" >>"$log" 2>&1; then
    give_up "its device failed to build or run a test kernel, see $log"
fi

rm -rf "$vendors"
mv "$vendors.new" "$vendors"
say "Intel CPU OpenCL runtime ready ($vendors); make test runs on it too"
