#!/usr/bin/env bash
# The test command: formatting, lints with warnings as errors, every test of the workspace
# (unit, integration, CLI, end-to-end harness, doc tests), built optimised (profile o3-test:
# o3 without its LTO, see Cargo.toml) so the physics tests run fast, and the loom model check
# of mpm-core's parallel primitives. mpm-bench's Slurm test starts a one-node Slurm of its own
# (scripts/slurm-local.sh) and stops it: it needs root and the packages the bootstrap installs.
set -euo pipefail
cd "$(dirname "$0")/.."
scripts/bootstrap.sh
[ -f "$HOME/.cargo/env" ] && . "$HOME/.cargo/env"

step() { printf '\n==> %s\n' "$*" >&2; }
start=$(date +%s)

step "cargo fmt --check"
cargo fmt --all -- --check

step "cargo clippy (all targets, -D warnings)"
cargo clippy --workspace --all-targets --profile o3 -- -D warnings

step "cargo test (profile o3-test: o3 without LTO)"
cargo test --workspace --profile o3-test

# loom swaps the team's atomics for model-checked ones under `--cfg loom`; its own target
# directory keeps the normal build's artefacts valid. About 1.5 minutes from scratch, a few
# seconds once built.
step "loom model check of the parallel primitives (mpm-core parallel::)"
RUSTFLAGS="--cfg loom" CARGO_TARGET_DIR=target/loom cargo test --profile o3-test -p mpm-core --lib parallel::

step "done in $(( $(date +%s) - start )) s"
