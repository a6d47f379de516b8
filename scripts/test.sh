#!/usr/bin/env bash
# The test command: formatting, lints with warnings as errors, and every test of the
# workspace (unit, integration, CLI, end-to-end harness, doc tests), built optimised
# (profile o3) so the physics tests run fast.
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

step "cargo test (profile o3)"
cargo test --workspace --profile o3

step "done in $(( $(date +%s) - start )) s"
