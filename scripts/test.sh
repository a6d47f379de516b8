#!/usr/bin/env bash
# The test command: formatting, lints with warnings as errors, every test of the workspace
# (unit, integration, CLI, end-to-end harness, doc tests), built optimised (profile o3-test:
# o3 without its LTO, see Cargo.toml) so the physics tests run fast, the bundle test, the loom
# model check of mpm-core's parallel primitives, the work counters against their committed
# snapshot, the fault-injection suite (scripts/fault-injection.sh: kills, a full disk, a
# read-only folder; it needs root) and the CI job files run for real
# (scripts/ci-recipes-test.sh). mpm-bench's Slurm test starts a one-node Slurm of its own
# (scripts/slurm-local.sh) and stops it: it needs root and the packages the bootstrap installs.
set -euo pipefail
cd "$(dirname "$0")/.."
scripts/bootstrap.sh
[ -f "$HOME/.cargo/env" ] && . "$HOME/.cargo/env"

start=$(date +%s)
# Each step says when it started (seconds since the start), so a slow step shows in the log.
step() { printf '\n==> [%4d s] %s\n' "$(( $(date +%s) - start ))" "$*" >&2; }

step "cargo fmt --check"
cargo fmt --all -- --check

# In the tests' profile: the build scripts, their outputs and the proc macros clippy builds are
# then the test build's too.
step "cargo clippy (all targets, -D warnings)"
cargo clippy --workspace --all-targets --profile o3-test -- -D warnings

step "the campaign scripts' shared steps (scripts/campaign-steps-test.sh)"
scripts/campaign-steps-test.sh

# The AVX-512 kernels' tests run where the CPU has AVX-512F and say they are skipped where
# it does not; told what /proc/cpuinfo lists, they fail instead if its flags and the
# run-time detection disagree (a skip on a CPU that has it).
export MPM_CPU_HAS_AVX512=0
if grep -qw avx512f /proc/cpuinfo 2>/dev/null && grep -qw avx2 /proc/cpuinfo; then MPM_CPU_HAS_AVX512=1; fi
# The campaigns the harness's tests run find or build their `mpm` as `mpm-bench run` does. The
# o3 one is the tests' own (profile o3-test: o3's optimisation without its LTO), which this
# build makes: named by MPM_BENCH_SOLVER_O3, with MPM_BENCH_CARGO_PROFILE_O3 saying its
# profile, instead of o3 with LTO from scratch (minutes), or a `cargo build -p mpm-cli` of
# o3-test, which unifies the dependencies' features otherwise and builds the MPI binding's
# chain again. The o0 one is built by the campaign test, as `mpm-bench run` builds a level.
# mpm-bench's Slurm test is left out here and runs below, beside the bundle test and loom.
step "cargo test (profile o3-test: o3 without LTO; MPM_CPU_HAS_AVX512=$MPM_CPU_HAS_AVX512)"
MPM_BENCH_CARGO_PROFILE_O3=o3-test MPM_BENCH_SOLVER_O3="$PWD/target/o3-test/mpm" \
    cargo test --workspace --profile o3-test -- --skip campaigns_through_a_one_node_slurm

# The fault-injection suite, with the programs the tests built (target/o3-test/mpm-bench,
# target/o3-test/mpm as both solvers): the smoke campaign (three repetitions) killed with
# SIGKILL at 20 seeded random moments and resumed to exactly the rows of an uninterrupted
# one, the same campaign into a tmpfs that fills up and resumed when space is back, a
# read-only results folder refused up front. It mounts tmpfs file systems: root only (it
# fails elsewhere, saying so). About 2-3 minutes; FAULT_SEED=N draws other kill moments.
step "the fault-injection suite (scripts/fault-injection.sh)"
MPM_BENCH=target/o3-test/mpm-bench MPM_BENCH_SOLVER_O3=target/o3-test/mpm MPM_BENCH_SOLVER_O0=target/o3-test/mpm \
    scripts/fault-injection.sh

# mpm-bench's Slurm test (tests/slurm.rs: a one-node Slurm of its own, started and stopped)
# spends most of its two minutes waiting on the cluster, so it runs in the background beside
# the bundle test and loom, which build and compute but time nothing. It runs copies of the
# two solvers the tests built (the bundle test rebuilds `mpm` in place for a while). Not beside
# the fault-injection suite, whose kill moments are scaled to an undisturbed campaign's time,
# nor the CI recipes, whose gate times both sides. Its output is printed when it ends.
step "the Slurm test (mpm-bench tests/slurm.rs), started in the background"
# (Asked of the whole workspace, as built above: `-p mpm-bench` alone unifies the features of
# the dependencies otherwise and would build them again.)
slurm_test=$(cargo test --workspace --profile o3-test --no-run 2>&1 |
    sed -n 's/.*Executable tests\/slurm\.rs (\(.*\))$/\1/p')
[ -n "$slurm_test" ] && [ -x "$slurm_test" ] || { echo "test.sh: cannot find the Slurm test's binary" >&2; exit 1; }
slurm_dir=$(mktemp -d)
cp target/o3-test/mpm "$slurm_dir/mpm-o3"
cp target/o0/mpm "$slurm_dir/mpm-o0"
(cd mpm-bench && MPM_BENCH_SOLVER_O3="$slurm_dir/mpm-o3" MPM_BENCH_SOLVER_O0="$slurm_dir/mpm-o0" \
    "../$slurm_test" --nocapture) > "$slurm_dir/slurm-test.log" 2>&1 &
slurm_pid=$!
# Whatever fails meanwhile, the Slurm test ends (and stops its cluster) before this script does.
trap 'wait "$slurm_pid" 2> /dev/null || true; rm -rf "$slurm_dir"' EXIT

# The self-contained bundle for a machine without a toolchain (scripts/bundle.sh), made at
# profile o3-test from the builds above and run unpacked without cargo: its libraries, the
# smoke campaign through ./manycore.sh and its archive's size, the manycore preset's dry run
# capped to this machine's cores. A few minutes.
step "the bundle (scripts/bundle-test.sh)"
scripts/bundle-test.sh

# loom swaps the team's atomics for model-checked ones under `--cfg loom`; its own target
# directory keeps the normal build's artefacts valid. About a minute from scratch, a few
# seconds once built; the model check itself takes a second or two, so mpm-core is built in 16
# codegen units here (its one unit of o3-test is for the time steps the other tests run).
step "loom model check of the parallel primitives (mpm-core parallel::)"
RUSTFLAGS="--cfg loom" CARGO_TARGET_DIR=target/loom cargo test --profile o3-test -p mpm-core --lib \
    --config 'profile.o3-test.package.mpm-core.codegen-units=16' parallel::

step "the Slurm test, waited for"
if ! wait "$slurm_pid"; then
    cat "$slurm_dir/slurm-test.log" >&2
    echo "test.sh: mpm-bench's Slurm test failed (its output above)" >&2
    exit 1
fi
grep -E '^(running|test |Slurm )' "$slurm_dir/slurm-test.log" >&2

# The work counters are the same on every machine for a given commit: the ci preset's cells
# run once (about 20 s, the o3-test build: the counters do not depend on the optimisation)
# and compared exactly with the committed snapshot; an intended change rewrites it
# (`mpm-bench work-snapshot --write ci/work-baseline.json`).
step "the work counters against ci/work-baseline.json (mpm-bench work-snapshot --check)"
MPM_BENCH_SOLVER_O3=target/o3-test/mpm target/o3-test/mpm-bench work-snapshot --check ci/work-baseline.json --no-build

# The CI job files in ci/: actionlint, and the GitLab gate end to end under gitlab-ci-local
# on a temporary clone of HEAD (its own build of both sides: a few minutes the first time).
step "the CI recipes (scripts/ci-recipes-test.sh)"
scripts/ci-recipes-test.sh

step "the docs' measured tables against results/ (scripts/docs-tables.sh --check)"
scripts/docs-tables.sh --check
step "ARCHITECTURE.md's code map against the source files (scripts/codemap-check.sh)"
scripts/codemap-check.sh

step "done in $(( $(date +%s) - start )) s"
