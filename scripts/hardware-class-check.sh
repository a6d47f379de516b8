#!/usr/bin/env bash
# Two hosts of one hardware class compare: the `smoke` campaign run twice on this machine,
# the second time with another /etc/machine-id bind-mounted in a private mount namespace
# (what a fresh VM of the same image and hardware has: another machine id, so another exact
# host identity and results folder), then `regress` between the two. It must say they
# compare (exit 0 or 1: a verdict), never "incomparable" (exit 2). Needs root (unshare,
# mount) and the o3 and o0 builds.
#
#   scripts/hardware-class-check.sh [OUT]      # default OUT: results/local/hardware-class
#
# OUT gets a/ and b/ (the two campaigns, each under its own fingerprint), verdict.json and
# verdict.md. Single runs per cell (smoke) are noisy: the efficiency checks use a 25 %
# tolerance; the work counters are compared exactly.
set -euo pipefail
cd "$(dirname "$0")/.."
out="${1:-results/local/hardware-class}"
bench=target/o3/mpm-bench
for b in "$bench" target/o3/mpm target/o0/mpm; do
    [ -x "$b" ] || { echo "hardware-class-check: $b is missing: cargo build --profile o3 -p mpm-cli -p mpm-bench && cargo build --profile o0 -p mpm-cli --bin mpm" >&2; exit 1; }
done
[ "$(id -u)" -eq 0 ] || { echo "hardware-class-check: needs root (a private mount of /etc/machine-id)" >&2; exit 1; }
rm -rf "$out/a" "$out/b"
mkdir -p "$out"
"$bench" run --preset smoke --no-build --quiet --out "$out/a"
fake=$(mktemp)
trap 'rm -f "$fake"' EXIT
od -An -N16 -tx1 /dev/urandom | tr -d ' \n' > "$fake"
echo >> "$fake"
echo "the second campaign under machine id $(cat "$fake") (this host's: $(cat /etc/machine-id))" >&2
unshare --mount --propagation private sh -c \
    "mount --bind '$fake' /etc/machine-id && exec '$bench' run --preset smoke --no-build --quiet --out '$out/b'"
set +e
"$bench" regress --baseline "$out/a" --current "$out/b" --metrics efficiency,work --tolerance 0.25 \
    --json "$out/verdict.json" --markdown "$out/verdict.md"
rc=$?
set -e
fa=$(ls "$out/a"); fb=$(ls "$out/b")
echo "fingerprints: $fa and $fb; regress exit $rc" >&2
[ "$fa" != "$fb" ] || { echo "hardware-class-check: the two campaigns have one fingerprint: the machine id did not change" >&2; exit 1; }
[ "$rc" -ne 2 ] || { echo "hardware-class-check: the two hosts of one hardware class did not compare" >&2; exit 1; }
exit "$rc"
