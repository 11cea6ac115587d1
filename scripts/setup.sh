#!/usr/bin/env bash
# Idempotent set-up behind `make demo` and `make test`: a local .venv with clray installed
# editable (plus dev tools), and an OpenCL platform. Quiet, and quick when all is in place.
set -euo pipefail
cd "$(dirname "$0")/.."

python=${PYTHON:-python3}
venv_python=.venv/bin/python
stamp=.venv/.clray-installed

say() { echo "setup: $*" >&2; }
as_root_with_apt() { [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null; }
apt_install() {
    say "apt-get install $*"
    DEBIAN_FRONTEND=noninteractive apt-get update -qq
    DEBIAN_FRONTEND=noninteractive apt-get install -y -qq "$@" >/dev/null
}

if ! "$python" -c 'import sys; sys.exit(sys.version_info < (3, 11))' 2>/dev/null; then
    say "clray needs Python 3.11 or newer as '$python' (set PYTHON=... to choose another)"
    exit 1
fi

if [ ! -x "$venv_python" ]; then
    say "creating .venv"
    if ! "$python" -m venv .venv >/dev/null 2>&1; then
        # Debian ships venv's pip bootstrap separately, in python3-venv.
        rm -rf .venv
        if as_root_with_apt; then
            apt_install python3-venv
            "$python" -m venv .venv
        else
            say "'$python -m venv' failed: install python3-venv (Debian) and run again"
            exit 1
        fi
    fi
fi

# Reinstall only when pyproject.toml (dependencies, extras) is newer than the last install.
if [ ! -f "$stamp" ] || [ pyproject.toml -nt "$stamp" ]; then
    say "installing clray (editable) with dev tools into .venv"
    "$venv_python" -m pip install -q --disable-pip-version-check -e '.[dev,plot,exr,dask,tune,denoise]'
    touch "$stamp"
fi

has_platform() { "$venv_python" -c 'import pyopencl as cl; cl.get_platforms()' >/dev/null 2>&1; }

if ! has_platform; then
    if as_root_with_apt; then
        apt_install pocl-opencl-icd ocl-icd-libopencl1 clinfo
    else
        say "no OpenCL platform and not root: installing PoCL from pip (clray[pocl])"
        "$venv_python" -m pip install -q --disable-pip-version-check -e '.[pocl]'
    fi
    if ! has_platform; then
        say "still no OpenCL platform found; see Troubleshooting in README.md (clinfo -l)"
        exit 1
    fi
fi
