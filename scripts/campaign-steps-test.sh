#!/usr/bin/env bash
# The test of scripts/campaign-steps.sh, the steps reproduce.sh and manycore.sh share: a
# campaign command that fails one run (exit status 1, as `mpm-bench run` does) still gives
# its folder and the failed run's line, every analysis step after it runs, a failed step
# does not stop the next, and the end names the failed run and step with status 1; a
# campaign without failures ends with status 0. Runs in a second, without cargo.
set -euo pipefail
here=$(CDPATH= cd -- "$(dirname -- "$0")" && pwd)
. "$here/campaign-steps.sh"
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
fail() { echo "campaign-steps-test: $*" >&2; exit 1; }

# `mpm-bench run` as the scripts see it: the folder on standard output, the runs' lines on
# stderr, exit status 1 when a run failed.
campaign_of() { # campaign_of STATUS
    echo "campaign folder: $work/c"
    echo "[1/2] Model1 dd t1 : ok" >&2
    [ "$1" = 0 ] || echo "[2/2] Model2 dd t2 : failed (solver exited with status 101)" >&2
    return "$1"
}

run_campaign "$work" campaign_of 1 > /dev/null 2>&1
[ "$campaign_status" = 1 ] || fail "the campaign's exit status is $campaign_status, not 1"
[ "$campaign" = "$work/c" ] || fail "the campaign folder is '$campaign', not $work/c"
[ "$campaign_failed" = "[2/2] Model2 dd t2 : failed (solver exited with status 101)" ] ||
    fail "the failed runs are '$campaign_failed'"
analyse "figures" true 2> /dev/null
analyse "claims" false 2> /dev/null
analyse "report" touch "$work/report" 2> /dev/null
[ -f "$work/report" ] || fail "the step after a failed one did not run"
[ "${broken[*]}" = "claims" ] || fail "the failed steps are '${broken[*]}', not claims"
if name_failures reproduce 2> "$work/said"; then fail "a failed run ended with status 0"; fi
grep -q "Model2 dd t2 : failed" "$work/said" && grep -q "these steps failed: claims" "$work/said" ||
    fail "the end does not name the failed run and step: $(cat "$work/said")"

broken=()
run_campaign "$work" campaign_of 0 > /dev/null 2>&1
[ "$campaign_status" = 0 ] && [ -z "$campaign_failed" ] || fail "a campaign without failures reads as failed"
name_failures reproduce 2> "$work/said" || fail "a campaign without failures ended with status 1: $(cat "$work/said")"
echo "campaign-steps-test: ok"
