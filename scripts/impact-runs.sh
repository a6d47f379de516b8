#!/usr/bin/env bash
# The committed hypervelocity impact results (results/impact/): the paper's small model at
# 2.12, 1.59 and 1.06 mm cells and the large model (0.21 mm spacing, 1.0 mm cells), each to
# 30.6 µs after impact with domain decomposition on 2 threads pinned to CPUs 0 and 1. Each run
# writes <results>/<run>/{summary.json, stdout.txt, time.txt, radiograph_final.png,
# history.png}; at the end the README's table is regenerated from the summaries
# (mpm-bench impact-table) into the template scripts/impact-readme.template.md.
#
# Usage: scripts/impact-runs.sh [--force] [all | small | large | RUN ...]
#   RUN is one of small-cell-2.12mm, small-cell-1.59mm, small-cell-1.06mm, large.
#   A run whose summary.json exists is skipped unless --force.
# Environment:
#   IMPACT_RESULTS     results folder (default results/impact)
#   IMPACT_EXTRA_ARGS  more options for every `mpm run impact`, e.g. "--steps 3" for a smoke
#                      test into a temporary IMPACT_RESULTS
#
# Times on the development machine (2 cores), on the sparse grid (the impact's default): the
# small model 21 s, 42 s and 1.3 min at 2.12, 1.59 and 1.06 mm cells (at 425f254); the large
# model (13.5 M particles) 14.3 min with a 3.6 GiB peak at fbc342e (17.6 min at 425f254;
# 8.3 GiB on the dense adaptive grid at an earlier commit, --grid adaptive: ARCHITECTURE.md,
# "Memory of the adaptive grid: the sparse grid").
set -euo pipefail
cd "$(dirname "$0")/.."
[ -f "$HOME/.cargo/env" ] && . "$HOME/.cargo/env"

results=${IMPACT_RESULTS:-results/impact}
extra=${IMPACT_EXTRA_ARGS:-}
force=0
declare -A model=(
    [small-cell-2.12mm]="--cell 2.12e-3"
    [small-cell-1.59mm]="--cell 1.59e-3"
    [small-cell-1.06mm]="--cell 1.06e-3"
    [large]="--spacing 0.21e-3 --cell 1.0e-3"
)
small=(small-cell-2.12mm small-cell-1.59mm small-cell-1.06mm)

runs=()
for a in "$@"; do
    case "$a" in
        --force) force=1 ;;
        all) runs+=("${small[@]}" large) ;;
        small) runs+=("${small[@]}") ;;
        -h|--help) sed -n '2,20p' "$0" | sed 's/^# \{0,1\}//'; exit 0 ;;
        *)
            if [ -z "${model[$a]+x}" ]; then
                echo "error: unknown run '$a': use all, small, large or one of ${!model[*]}" >&2
                exit 2
            fi
            runs+=("$a") ;;
    esac
done
[ ${#runs[@]} -eq 0 ] && runs=("${small[@]}" large)

if [ ! -x /usr/bin/time ]; then
    echo "error: /usr/bin/time is missing (it records each run's time.txt): install the 'time' package" >&2
    exit 1
fi

cargo build --profile o3 -p mpm-cli -p mpm-bench
mpm=target/o3/mpm
mkdir -p "$results"

for run in "${runs[@]}"; do
    dir="$results/$run"
    if [ -f "$dir/summary.json" ] && [ "$force" -eq 0 ]; then
        echo "==> $run: $dir/summary.json exists, skipped (--force to rerun)" >&2
        continue
    fi
    mkdir -p "$dir"
    rm -f "$dir/summary.json" "$dir/radiograph_final.png" "$dir/history.png"
    echo "==> $run" >&2
    # shellcheck disable=SC2086 # the model's options and IMPACT_EXTRA_ARGS are word lists
    /usr/bin/time -v -o "$dir/time.txt" "$mpm" run impact ${model[$run]} \
        --strategy dd --threads 2 --cpus 0,1 --end-time 30.6e-6 $extra \
        --json "$dir/summary.json" --radiograph "$dir" > "$dir/stdout.txt"
done

target/o3/mpm-bench impact-table --results "$results" \
    --template scripts/impact-readme.template.md --out "$results/README.md"
echo "==> $results/README.md" >&2
