#!/usr/bin/env bash
# The paper's scaling on a machine of many cores, in one command and one short reservation:
# the `manycore` campaign (Taylor Models 1-4, threads 1/2/4/8/16 as far as the machine has
# cores, every parallel strategy, paired cells; its estimated duration printed first), the
# memory-bandwidth ceiling, Figures 7-14, the claims C1-C7 and the report, packed into one
# archive of at most 16 MiB to carry home.
#
#   ./manycore.sh                      # from an unpacked bundle (scripts/bundle.sh makes it)
#   scripts/manycore.sh                # from a checkout (builds mpm and mpm-bench first)
#   ./manycore.sh --dry-run            # the plan and its estimated duration only
#   ./manycore.sh --out DIR            # the results tree (default: results)
#   ./manycore.sh --preset smoke       # another preset through the same steps (the test)
#
# Thread counts above the machine's usable cores are skipped and said, never run
# oversubscribed. Other options go to `mpm-bench run` (e.g. `--reps 5`). Failed runs do not
# stop it: the figures, claims and report are made from the runs that ended, and it exits 1
# naming the failed runs (and any step that failed). The archive,
# <out>/<campaign>-<machine fingerprint>.tar.gz, holds the campaign folder: runs.csv,
# manifest.json, topology.xml, bandwidth.json, figures/, claims.md, report/ and json/ (the
# runs' summaries, left out if the archive would be over 16 MiB with them).
set -euo pipefail
here=$(CDPATH= cd -- "$(dirname -- "$0")" && pwd)

out=results
preset=manycore
dry=0
args=()
while [ $# -gt 0 ]; do
    case "$1" in
        --out) out="$2"; shift 2 ;;
        --out=*) out="${1#--out=}"; shift ;;
        --preset) preset="$2"; shift 2 ;;
        --preset=*) preset="${1#--preset=}"; shift ;;
        --dry-run) dry=1; args+=(--dry-run --estimate); shift ;;
        -h|--help) sed -n '2,20p' "$0" | sed 's/^# \{0,1\}//'; exit 0 ;;
        *) args+=("$1"); shift ;;
    esac
done

if [ -x "$here/bin/mpm-bench" ]; then
    bench="$here/bin/mpm-bench"            # the bundle: its own solvers, presets, libraries
else
    repo="$here/.."                       # a checkout
    (cd "$repo" && scripts/bootstrap.sh)
    [ -f "$HOME/.cargo/env" ] && . "$HOME/.cargo/env"
    (cd "$repo" && cargo build --profile o3 -p mpm-cli -p mpm-bench && cargo build --profile o0 -p mpm-cli --bin mpm)
    bench="$(cd "$repo" && pwd)/target/o3/mpm-bench"
fi

logs=$(mktemp -d)
trap 'rm -rf "$logs"' EXIT
. "$here/campaign-steps.sh"

step "machine topology"
"$bench" topology --threads 1,2,4,8,16 | tee "$logs/topology"
cores=$(sed -n 's/^Summary .* \([0-9][0-9]*\) core(s), .*/\1/p' "$logs/topology")

step "campaign: preset $preset"
run_campaign "$logs" "$bench" run --preset "$preset" --out "$out" --no-build "${args[@]}"
[ "$dry" = 1 ] && exit "$campaign_status"
if [ -z "$campaign" ] || [ ! -f "$campaign/runs.csv" ]; then
    echo "manycore: the campaign wrote no results (exit status $campaign_status); nothing to analyse" >&2
    exit 1
fi
[ "$campaign_status" = 0 ] || echo "manycore: some runs failed (exit status $campaign_status); analysing the others" >&2

# Each analysis step runs even when one before it failed; the failures are named at the end.
threads=$(for t in 1 2 4 8 16; do if [ "$t" -le "${cores:-1}" ]; then printf "%s," "$t"; fi; done)
analyse "memory-bandwidth ceiling (STREAM triad, threads ${threads%,}, close and spread)" \
    "$bench" bandwidth --threads "${threads%,}" --pin close --pin spread --out "$campaign/bandwidth.json"
analyse "figures 7-14, the memory figure and points.csv" \
    "$bench" figures --results "$campaign" --out "$campaign/figures"
analyse "the paper's claims C1-C7" "$bench" claims --results "$campaign" --markdown "$campaign/claims.md"
analyse "the report" "$bench" report --results "$campaign" --out "$campaign/report"

step "packing"
parent=$(dirname "$campaign")
folder=$(basename "$campaign")
archive="$out/$folder-$(basename "$parent").tar.gz"
limit=$((16 * 1024 * 1024))
# Checkpoints of runs that did not finish can be gigabytes: never carried.
tar -C "$parent" -czf "$archive" --exclude="$folder/checkpoints" "$folder"
if [ "$(stat -c %s "$archive")" -gt "$limit" ]; then
    echo "manycore: over 16 MiB with the runs' JSON summaries; packing without json/" >&2
    tar -C "$parent" -czf "$archive" --exclude="$folder/checkpoints" --exclude="$folder/json" "$folder"
fi
size=$(stat -c %s "$archive")
if [ "$size" -gt "$limit" ]; then
    echo "manycore: $archive is $size bytes, over 16 MiB even without json/: carry $campaign as it is" >&2
    broken+=("packing")
fi

step "done: $archive ($((size / 1024)) KiB); open $campaign/report/index.html"
status=0
name_failures manycore || status=1
echo "$archive"
exit "$status"
