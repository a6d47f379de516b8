#!/usr/bin/env bash
# Cost of the added physics (bulk viscosity, energy checks, the mid-step velocity
# gradient of the energy-conserving work) on the Taylor bar's serial step: three `mpm`
# binaries timed in interleaved rounds (the order rotates through all six permutations), Taylor
# Model 2, serial, STEPS steps, pinned to CPU 0; prints the median ratio of ns per
# particle-step with a bootstrap 95 % interval and the ratio of the minima.
#
# Usage: scripts/physics-cost.sh BEFORE START AFTER OUT [ROUNDS] [STEPS]
#   BEFORE  mpm built before the physics (branch bench/physics-cost-before: f04b4e1 with the
#           later speed commits of the scatter kernels and the floor by cast)
#   START   mpm at the start of the change being measured
#   AFTER   mpm after it
#   OUT     folder for the runs' JSON summaries (A-i, M-i, B-i) and summary.txt
# Defaults: 20 rounds of 100 steps (about 7 minutes here). Run on a quiet host.
set -euo pipefail
[ $# -ge 4 ] || { sed -n '2,15p' "$0" | sed 's/^# \{0,1\}//'; exit 2; }
declare -A BIN=([A]=$1 [M]=$2 [B]=$3)
out=$4 rounds=${5:-20} steps=${6:-100}
mkdir -p "$out"
orders=("A M B" "M B A" "B A M" "A B M" "M A B" "B M A")
for i in $(seq 1 "$rounds"); do
    for w in ${orders[$(((i - 1) % 6))]}; do
        "${BIN[$w]}" run taylor --model 2 --strategy serial --steps "$steps" --cpus 0 --quiet --json "$out/$w-$i.json"
    done
done
python3 - "$out" "$rounds" <<'PY' | tee "$out/summary.txt"
import json, random, statistics as st, sys
d, p = sys.argv[1], int(sys.argv[2])
ns = lambda w, i: json.load(open(f"{d}/{w}-{i}.json"))["ns_per_particle_step"]
random.seed(1)
def ratio(x, y):
    r = [ns(x, i) / ns(y, i) for i in range(1, p + 1)]
    b = sorted(st.median(random.choices(r, k=len(r))) for _ in range(10000))
    mins = min(ns(x, i) for i in range(1, p + 1)) / min(ns(y, i) for i in range(1, p + 1))
    return f"median {st.median(r):.4f}, bootstrap 95 % [{b[250]:.4f}, {b[9750]:.4f}], ratio of minima {mins:.4f}"
print(f"{p} rounds; A = before, M = start, B = after; ns per particle-step")
print("M/A:", ratio("M", "A"))
print("B/A:", ratio("B", "A"))
print("B/M:", ratio("B", "M"))
PY
