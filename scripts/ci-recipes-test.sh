#!/usr/bin/env bash
# The CI recipes in ci/ run for real (scripts/test.sh runs this):
#   1. actionlint accepts every GitHub workflow in ci/github/ (and refuses a broken copy,
#      so a check that checks nothing fails here);
#   2. the GitLab job ci/gitlab/efficiency-gate.yml runs end to end under gitlab-ci-local
#      (shell executor) on a temporary clone of HEAD with two commits, the merge request's
#      base and the candidate: exit 0 when the candidate's code is the base's, exit 1 when
#      the candidate carries an injected 50 % step slowdown (the time-per-step check fails).
# The job builds the candidate and the base (from a worktree of the base commit) itself.
# Both builds share CARGO_TARGET_DIR=target/recipe-test, in profile o3-test (o3 without its
# link-time optimisation), so that the dependencies are built once.
# The cells are one small Model 1 cell, 6 pairs, at a tolerance of 25 %: this checks the
# recipe, not the gate's error rates (`mpm-bench calibrate --design ab` measures those).
set -euo pipefail
cd "$(dirname "$0")/.."
repo=$(pwd)
tools="${MPM_TOOLS_DIR:-$HOME/.cache/mpm-bench-tools}"
actionlint="$tools/venv/bin/actionlint"
glci="$tools/npm/node_modules/.bin/gitlab-ci-local"
for t in "$actionlint" "$glci"; do
    [ -x "$t" ] || { echo "ci-recipes-test: $t is missing: run scripts/bootstrap.sh" >&2; exit 1; }
done
step() { printf '\n==> %s\n' "$*" >&2; }

step "actionlint ci/github/*.yml"
"$actionlint" ci/github/*.yml
tmp=$(mktemp -d)
trap 'rm -rf "$tmp" "$repo"/target/recipe-test/ab-src-* "$repo"/target/recipe-test/ab-bin-*' EXIT
sed 's/runs-on:/runs_on:/' ci/github/efficiency-gate.yml > "$tmp/broken.yml"
if "$actionlint" "$tmp/broken.yml" >/dev/null 2>&1; then
    echo "ci-recipes-test: actionlint accepted a workflow without runs-on" >&2
    exit 1
fi

step "the GitLab efficiency gate under gitlab-ci-local, on a clone with two commits"
# Both sides build with profile o3-test (the job's MPM_BENCH_CARGO_PROFILE_O3) into
# target/recipe-test, seeded with a copy of this checkout's o3-test build when there is one
# (after scripts/test.sh's tests): the dependencies are then built already, and only the
# workspace's crates are built, once per side. A copy, never links: a build writes its
# outputs in place.
if [ -d target/o3-test ] && [ ! -d target/recipe-test/o3-test ]; then
    mkdir -p target/recipe-test
    cp -r target/o3-test target/recipe-test/o3-test
fi
git clone -q "$repo" "$tmp/repo"
cd "$tmp/repo"
git config user.email test@example.com
git config user.name "recipe test"
git remote set-url origin https://gitlab.example.com/mpm/mpm-bench.git
cp ci/gitlab/efficiency-gate.yml .gitlab-ci.yml
cat > ab-test.toml <<'TOML'
name = "ab-test"
description = "One Model 1 cell, DD, 2 threads, 6 pairs: the recipe test's cells"
scenario = "taylor"
models = [1]
threads = [2]
strategies = ["dd"]
opt = ["o3"]
reps = 6
pin = "close"
grid = "fixed"
seed = 3
timeout = "5m"
paired = { blocks = 2 }

[budget]
steps = 14
warmup = 2
TOML
# The candidate also bumps the workspace's version, as a release's merge request would. Both
# sides build into one target folder, and their build scripts record their commits: with the
# same package ids each side's build would replace the other's artefacts, and the second job
# would build both sides again (minutes); with different versions both sides' artefacts stay.
sed -i '/^\[workspace.package\]/,/^\[/s/^version = "\(.*\)"/version = "\1-candidate"/' Cargo.toml
sed -i '/^name = "mpm-\(bench\|cli\|core\|host\|spec\)"$/{n;s/^version = "\(.*\)"/version = "\1-candidate"/}' Cargo.lock
grep -q -- '-candidate"' Cargo.toml && [ "$(grep -c -- '-candidate"' Cargo.lock)" = 5 ] \
    || { echo "ci-recipes-test: cannot bump the candidate's version in Cargo.toml and Cargo.lock" >&2; exit 1; }
git add .gitlab-ci.yml ab-test.toml Cargo.toml Cargo.lock
git commit -q -m "The candidate: the gate's job and its cells, a new version"
# The build scripts watch the index (the dirty flag). Written in the same second as the files
# it lists, their entries are "racily clean" and the next `git status` (the harness's record
# of the checkout) writes it again, and the second job would build the candidate again: an
# index written a second later lists nothing racy and stays as it is.
sleep 1
git update-index -q --refresh --force-write-index
base=$(git rev-parse HEAD~1)

gate() {
    rm -rf ab .gitlab-ci-local
    set +e
    GCL_IGNORE_PREDEFINED_VARS=CI_PIPELINE_SOURCE,CI_MERGE_REQUEST_DIFF_BASE_SHA \
        "$glci" --file .gitlab-ci.yml --force-shell-executor --no-color \
        --variable CI_PIPELINE_SOURCE=merge_request_event \
        --variable "CI_MERGE_REQUEST_DIFF_BASE_SHA=$base" \
        --variable "CARGO_TARGET_DIR=$repo/target/recipe-test" --variable MPM_BENCH_CARGO_PROFILE_O3=o3-test \
        --variable AB_PRESET=ab-test.toml --variable AB_WORK_SNAPSHOT= \
        --variable "AB_EXTRA=--tolerance 0.25 $1" \
        efficiency-gate > "$tmp/job.log" 2>&1
    local rc=$?
    set -e
    echo "$rc"
}

rc=$(gate "")
verdict=$(python3 -c 'import json,sys; print(json.load(open(sys.argv[1]))["verdict"])' ab/verdict.json 2>/dev/null || echo none)
if [ "$rc" -ne 0 ] || [ "$verdict" != pass ]; then
    tail -n 40 "$tmp/job.log" >&2
    echo "ci-recipes-test: the candidate equal to the base: gitlab-ci-local exit $rc, verdict $verdict (want 0, pass)" >&2
    exit 1
fi
echo "the candidate equal to the base: job passed (verdict $verdict)" >&2

rc=$(gate "--candidate-inject-step-slowdown 0.5")
failed=$(python3 -c 'import json,sys; v=json.load(open(sys.argv[1])); print(v["verdict"], sorted({c["metric"] for c in v["checks"] if c["outcome"] == "regressed"}))' ab/verdict.json 2>/dev/null || echo none)
if [ "$rc" -eq 0 ] || ! grep -q 'efficiency-gate finished in .* FAIL 1 ' "$tmp/job.log" || [ "$failed" != "fail ['time_per_step']" ]; then
    tail -n 40 "$tmp/job.log" >&2
    echo "ci-recipes-test: the candidate with a 50 % step slowdown: gitlab-ci-local exit $rc, verdict $failed (want a failed job, fail ['time_per_step'])" >&2
    exit 1
fi
echo "the candidate with an injected 50 % step slowdown: job failed (verdict $failed)" >&2
