#!/usr/bin/env bash
# Fills .gpu-wheels/ (ignored by git) with what `bash scripts/gpu_check.sh OUT_DIR` needs on a
# GPU machine that has no network (docs/gpu.md):
#
#   bash scripts/gpu_wheels.sh
#
# - wheels for CPython 3.12 on manylinux x86-64 of every package clray, pyopencl and Kernel
#   Tuner need there beyond what that machine's Python has (numpy, pillow, pytest, tqdm,
#   matplotlib, scipy, pandas...), at the versions .venv has installed; and the pure-Python
#   pytest plugins the kernel tests use there (pytest-xdist with execnet: 8 processes on its
#   16 cores; pytest-timeout: a hung test stopped), at .venv's versions where it has them,
#   else the latest;
# - cpu_reference.npz: every example scene rendered on PoCL's CPU device here, at 160x90 with
#   the scene's samples per pixel, which the GPU run compares its images with (the GPU machine
#   has no CPU OpenCL device: PoCL's wheel is 58 MB, too large to carry). It records a digest
#   of clray's sources, so the GPU run says when it was made from other sources.
#
# Run it again after changing clray's sources or kernels. GPU_PYTHON (default 3.12) names the
# GPU machine's Python version; REFERENCE_SIZE (default 160x90) the references' size.
set -uo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.." || exit 1

venv_python=.venv/bin/python
dest=.gpu-wheels
gpu_python=${GPU_PYTHON:-3.12}
reference_size=${REFERENCE_SIZE:-160x90}
# pyopencl and its dependencies; Kernel Tuner (clray tune) and those of its dependencies that
# the GPU machine's Python lacks.
packages=(pyopencl pytools siphash24 platformdirs typing_extensions
          kernel_tuner jsonschema jsonschema-specifications referencing rpds-py attrs
          python-constraint2 xmltodict)
# pytest's plugins for the kernel-test step (py3-none-any wheels): .venv's version where it has
# one, else the latest. Without them the step runs the tests in one process and cannot stop a
# test that hangs.
plugins=(pytest-xdist execnet pytest-timeout)

say() { echo "gpu_wheels: $*" >&2; }

if [ ! -x "$venv_python" ]; then
    say "no .venv: run scripts/setup.sh (make setup) first"
    exit 1
fi

new=$dest.new
rm -rf "$new"
mkdir -p "$new" || exit 1
download() {  # NAME SPEC: SPEC's wheel for the GPU machine's Python into $new
    "$venv_python" -m pip download -q --disable-pip-version-check --no-deps \
        --only-binary=:all: --python-version "$gpu_python" --implementation cp \
        --platform manylinux_2_28_x86_64 --platform manylinux_2_27_x86_64 \
        --platform manylinux_2_17_x86_64 --platform manylinux2014_x86_64 \
        -d "$new" "$2" 2> >(grep -v "is ignored: it is neither" >&2)
}
installed() {  # NAME: its version in .venv, or nothing (and exit 1)
    "$venv_python" -c 'import importlib.metadata as m, sys; print(m.version(sys.argv[1]))' \
        "$1" 2>/dev/null
}
for name in "${packages[@]}"; do
    version=$(installed "$name") || {
        say "$name is not installed in .venv (make setup installs clray's extras)"
        exit 1
    }
    say "$name==$version"
    if ! download "$name" "$name==$version"; then
        say "no wheel of $name==$version for CPython $gpu_python on manylinux x86-64"
        exit 1
    fi
done
for name in "${plugins[@]}"; do
    if version=$(installed "$name"); then
        spec="$name==$version"
    else
        spec=$name  # not in .venv: the latest
    fi
    say "$spec"
    if ! download "$name" "$spec"; then
        say "no wheel of $spec for CPython $gpu_python"
        exit 1
    fi
done

say "rendering the CPU references on PoCL at $reference_size (a minute or two)"
xdg=$(mktemp -d)
trap 'rm -rf "$xdg"' EXIT
# An empty cache folder: no tuning file of this machine's changes the references.
if ! env -u CLRAY_DEVICE -u PYOPENCL_CTX XDG_CACHE_HOME="$xdg" \
    POCL_CACHE_DIR="${POCL_CACHE_DIR:-$HOME/.cache/pocl/kcache}" \
    "$venv_python" scripts/gpu_check_steps.py references --out "$new/cpu_reference.npz" \
    --size "$reference_size" --device "Portable Computing Language"; then
    say "rendering the references failed"
    exit 1
fi

rm -rf "$dest"
mv "$new" "$dest"
ls -l "$dest" >&2
say "$(du -sh "$dest" | cut -f1) in $dest; carry it to the GPU machine with the checkout"
