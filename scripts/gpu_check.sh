#!/usr/bin/env bash
# One prepared command for a GPU machine without a network (docs/gpu.md):
#
#   bash scripts/gpu_check.sh OUT_DIR            on the GPU machine, .gpu-wheels/ carried along
#   bash scripts/gpu_check.sh OUT_DIR --cpu      the same steps on PoCL at tiny sizes (CI)
#
# Installs clray's needs from .gpu-wheels/ (scripts/gpu_wheels.sh fills it) into a temporary
# folder, never into the system Python; makes NVIDIA's OpenCL driver visible to pyopencl's ICD
# loader; then lists the devices, runs the kernel tests on the GPU, compares every example
# scene with the CPU's image, profiles spheres and the 327,680-triangle mesh, times kernel
# builds with the driver's register figures and runs `clray tune`, each step under a time limit
# of its own. Writes OUT_DIR/gpu_check.json (every figure), OUT_DIR/gpu_check.log and a few
# more files (8 at most, each under 16 MiB) within 8 minutes. Exit 0 when no step failed, ran
# out of time or was stopped (a step skipped for its stated reason, such as the GPU machine's
# missing CPU device, is no failure).
#
# PYTHON picks the interpreter (default: python3; with --cpu, .venv/bin/python where it exists).
# Further options go to scripts/gpu_check.py (--deadline S, --keep-work, --from-wheels).
# --deadline S (default 450, with --cpu 420) is the steps' time; this script stops the driver
# at S + 20 s (GPU_CHECK_LIMIT sets another limit): SIGTERM, on which it stops the running
# step's processes and writes its JSON and log, then SIGKILL 10 s later (and then the running
# step's process group, which the driver notes in a temporary file). Give the device tool
# a timeout_s of at least S + 40.
set -uo pipefail

repo=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)

if [ $# -lt 1 ] || [ "${1#-}" != "$1" ]; then
    echo "usage: bash scripts/gpu_check.sh OUT_DIR [--cpu] [--deadline S] [--keep-work]" >&2
    exit 2
fi
out=$1
shift

cpu=0
deadline=
previous=
for arg in "$@"; do
    case $arg in
        --cpu) cpu=1 ;;
        --deadline=*) deadline=${arg#--deadline=} ;;
    esac
    if [ "$previous" = "--deadline" ]; then
        deadline=$arg
    fi
    previous=$arg
done

python=${PYTHON:-}
if [ -z "$python" ]; then
    if [ "$cpu" = 1 ] && [ -x "$repo/.venv/bin/python" ]; then
        python=$repo/.venv/bin/python
    else
        python=python3
    fi
fi

mkdir -p "$out" || exit 2
# The driver keeps to its own deadline (450 s, 420 s with --cpu, or --deadline's) and may end a
# step stopped at it up to 10 s later; this limit only catches a driver that hangs itself, within
# the 8 minutes a GPU run has. SIGTERM first: the driver then stops the running step's process
# group, marks the step killed and writes its JSON and log summary (a few seconds), and exits;
# SIGKILL `grace` seconds later only where it could not.
if [ -z "$deadline" ]; then
    deadline=$([ "$cpu" = 1 ] && echo 420 || echo 450)
fi
whole=${deadline%%.*}
case $whole in
    ''|*[!0-9]*) whole=450 ;;  # the driver refuses such a --deadline itself
esac
limit=${GPU_CHECK_LIMIT:-$((whole + 20))}
grace=10
# Each step's processes run in a session of their own, which no signal to the driver reaches:
# the driver writes the running step's process group id here, and where the driver did not
# stop that group itself (SIGKILLed), it is killed below.
groups=$(mktemp -d "${TMPDIR:-/tmp}/gpu-check-groups.XXXXXX") || exit 2
trap 'rm -rf "$groups"' EXIT
GPU_CHECK_GROUP_FILE=$groups/step PYTHONUNBUFFERED=1 timeout -s TERM -k "$grace" "$limit" \
    "$python" "$repo/scripts/gpu_check.py" "$out" "$@"
rc=$?
if [ "$rc" = 124 ] || [ "$rc" = 137 ]; then
    pgid=$(cat "$groups/step" 2>/dev/null)
    case $pgid in
        ''|*[!0-9]*) ;;
        *)
            if kill -KILL -- "-$pgid" 2>/dev/null; then
                echo "gpu_check: killed the running step's processes (group $pgid)" |
                    tee -a "$out/gpu_check.log" >&2
            fi ;;
    esac
    echo "gpu_check: stopped after ${limit} s; $out/gpu_check.json holds the steps finished" |
        tee -a "$out/gpu_check.log" >&2
fi
exit "$rc"
