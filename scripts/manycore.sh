#!/usr/bin/env bash
# The paper's scaling on a machine with many cores, in one command and one short reservation:
# the `manycore` campaign (Taylor Models 1-4, threads 1/2/4/8/16 as far as the machine has
# cores, every strategy, paired cells), the memory-bandwidth ceiling, Figures 7-14, the
# claims C1-C7 and the report, packed into one archive to carry home.
#
#   ./manycore.sh                    # from an unpacked bundle (scripts/bundle.sh makes it)
#   scripts/manycore.sh              # from a checkout (builds the solver first)
#   ./manycore.sh --dry-run          # the plan and its time estimate only
#   ./manycore.sh --out DIR          # results tree (default: results)
#
# The campaign prints its estimate first (the preset is sized to about 6 minutes on 16
# cores) and never runs a thread count above the machine's usable cores: those cells are
# skipped and said. Other options go to `mpm-bench run` (e.g. `--reps 5`).
# The archive, <out>/manycore-<machine>.tar.gz, holds the campaign folder: runs.csv,
# manifest.json, topology.xml, bandwidth.json, figures/, claims.md, report/ (at most 16 MiB;
# the per-run JSON summaries are left out if they would make it larger).
set -euo pipefail
here=$(CDPATH= cd -- "$(dirname -- "$0")" && pwd)

out=results
dry=0
args=()
while [ $# -gt 0 ]; do
    case "$1" in
        --out) out="$2"; shift 2 ;;
        --out=*) out="${1#--out=}"; shift ;;
        --dry-run) dry=1; args+=("$1"); shift ;;
        -h|--help) sed -n '2,18p' "$0" | sed 's/^# \{0,1\}//'; exit 0 ;;
        *) args+=("$1"); shift ;;
    esac
done

if [ -x "$here/bin/mpm-bench" ]; then
    bench="$here/bin/mpm-bench"            # the bundle: its own solvers, presets, libraries
    cd "$here"
else
    cd "$here/.."                         # a checkout
    scripts/bootstrap.sh
    [ -f "$HOME/.cargo/env" ] && . "$HOME/.cargo/env"
    cargo build --profile o3 -p mpm-cli -p mpm-bench
    cargo build --profile o0 -p mpm-cli --bin mpm
    bench="$PWD/target/o3/mpm-bench"
fi

step() { printf '\n==> %s\n' "$*" >&2; }
step "machine topology"
"$bench" topology

step "campaign: preset manycore"
log=$(mktemp)
trap 'rm -f "$log"' EXIT
set +e
"$bench" run --preset manycore --out "$out" --no-build "${args[@]}" | tee "$log"
status=${PIPESTATUS[0]}
set -e
[ "$dry" = 1 ] && exit "$status"
campaign=$(sed -n 's/^campaign folder: //p' "$log" | tail -n 1)
if [ -z "$campaign" ] || [ ! -f "$campaign/runs.csv" ]; then
    echo "manycore: the campaign wrote no results (exit $status); nothing to analyse" >&2
    exit 1
fi
# The analysis goes on past failed runs: every figure that the finished runs allow.
[ "$status" = 0 ] || echo "manycore: some runs failed (exit $status); analysing the rest" >&2

cores=$("$bench" topology --cores)
threads=$(for t in 1 2 4 8 16; do [ "$t" -le "$cores" ] && printf '%s,' "$t"; done)
step "memory-bandwidth ceiling (STREAM triad, threads ${threads%,})"
"$bench" bandwidth --threads "${threads%,}" --out "$campaign/bandwidth.json"
step "figures 7-14, the memory figure and points.csv"
"$bench" figures --results "$campaign" --out "$campaign/figures"
step "the paper's claims C1-C7"
"$bench" claims --results "$campaign" --markdown "$campaign/claims.md"
step "the report"
"$bench" report --results "$campaign" --out "$campaign/report" >/dev/null

step "packing"
archive="$out/manycore-$(basename "$(dirname "$campaign")").tar.gz"
limit=$((16 * 1024 * 1024))
tar -C "$(dirname "$campaign")" -czf "$archive" "$(basename "$campaign")"
if [ "$(stat -c %s "$archive")" -gt "$limit" ]; then
    echo "manycore: over 16 MiB with the per-run summaries; packing without json/" >&2
    tar -C "$(dirname "$campaign")" -czf "$archive" --exclude="$(basename "$campaign")/json" \
        --exclude="$(basename "$campaign")/checkpoints" "$(basename "$campaign")"
fi
size=$(stat -c %s "$archive")
if [ "$size" -gt "$limit" ]; then
    echo "manycore: $archive is $size bytes, over 16 MiB" >&2
    exit 1
fi
step "done: $archive ($((size / 1024)) KiB); open $campaign/report/index.html"
echo "$archive"
exit "$status"
