#!/usr/bin/env bash
# The reproduce command: install what is missing, build the solver at both optimisation
# levels, measure the memory-bandwidth ceiling, run the quick campaign (every model, both
# strategies, both optimisation levels, threads 1/2/4/6/8, with step limits; the campaign
# prints its estimated duration when it starts), then draw the paper's Figures 7-14, check its
# claims and write the report, all from this machine's results.
#
# Everything goes to results/local/<machine-fingerprint>/<campaign>/ (not tracked by git):
# the figures to its figures/, the claims to claims.md, the report to report/, the bandwidth
# to bandwidth.json. The work tree stays clean: paper-figures/ holds the figures of the
# committed reference campaign and is only rewritten by scripts/paper-figures.sh. The
# committed reference campaigns under results/<fingerprint>/ are never written: they are
# elsewhere, and marked "reference" in their manifest, which `mpm-bench run` refuses as a
# resume target. Re-running on the same machine with the same solver binaries resumes the
# campaign (finished runs are skipped); another machine or a rebuilt solver starts a new
# folder. Options are passed on to `mpm-bench run`, e.g. `scripts/reproduce.sh --reps 3` or
# `--preset smoke`. Failed runs do not stop it: the figures, claims and report are made from
# the runs that ended, and it exits 1 naming the failed runs (and any step that failed).
set -euo pipefail
cd "$(dirname "$0")/.."
scripts/bootstrap.sh
[ -f "$HOME/.cargo/env" ] && . "$HOME/.cargo/env"

. scripts/campaign-steps.sh

step "building mpm and mpm-bench (profiles o3 and o0)"
cargo build --profile o3 -p mpm-cli -p mpm-bench
cargo build --profile o0 -p mpm-cli --bin mpm

preset=quick
args=()
while [ $# -gt 0 ]; do
    case "$1" in
        --preset) preset="$2"; shift 2 ;;
        --preset=*) preset="${1#--preset=}"; shift ;;
        *) args+=("$1"); shift ;;
    esac
done

step "machine topology"
target/o3/mpm-bench topology

step "campaign: preset $preset"
logs=$(mktemp -d)
trap 'rm -rf "$logs"' EXIT
run_campaign "$logs" target/o3/mpm-bench run --preset "$preset" --out results/local --no-build "${args[@]}"
if [ -z "$campaign" ] || [ ! -f "$campaign/runs.csv" ]; then
    echo "reproduce: the campaign wrote no results (exit status $campaign_status); nothing to analyse" >&2
    exit 1
fi
[ "$campaign_status" = 0 ] || echo "reproduce: some runs failed (exit status $campaign_status); analysing the others" >&2
# Record paths relative to the repository in the generated READMEs.
campaign=$(realpath --relative-to=. "$campaign")

# Each analysis step runs even when one before it failed; the failures are named at the end.
analyse "memory-bandwidth ceiling (STREAM triad) -> $campaign/bandwidth.json" \
    target/o3/mpm-bench bandwidth --threads 1,2 --out "$campaign/bandwidth.json"
analyse "figures 7-14, the memory figure and points.csv -> $campaign/figures/" \
    target/o3/mpm-bench figures --results "$campaign" --out "$campaign/figures"
analyse "the paper's claims C1-C7 on this machine" \
    target/o3/mpm-bench claims --results "$campaign" --markdown "$campaign/claims.md"
analyse "the campaign's report: one page to open first" \
    target/o3/mpm-bench report --results "$campaign" --out "$campaign/report" >/dev/null

step "done: results, figures, claims and report in $campaign; open the report:"
echo "$campaign/report/index.html"
name_failures reproduce || exit 1
