# The steps of a campaign script whose failed runs do not stop it, shared by
# scripts/reproduce.sh and scripts/manycore.sh (and the bundle's manycore.sh, beside which
# scripts/bundle.sh installs this file). Sourced, not run; the scripts run under `set -e`.
#
#   step TEXT...              a heading on stderr
#   run_campaign LOGS CMD...  run the campaign command CMD (`mpm-bench run ...`), shown as it
#                             comes and kept in the folder LOGS; sets campaign_status (its exit
#                             status: 1 when a run failed), campaign (the folder it named on
#                             standard output, empty when none) and campaign_failed (the lines of
#                             its runs that failed or were invalid)
#   analyse WHAT CMD...       run one analysis step; a failure is added to `broken` and the
#                             next step runs all the same
#   name_failures NAME        say on stderr which runs and steps failed; status 1 when any did
#                             or the campaign command failed, else 0

broken=()

step() { printf '\n==> %s\n' "$*" >&2; }

run_campaign() {
    local logs="$1"
    shift
    # Standard output (the folder) and stderr (the runs' lines) kept apart, both shown.
    set +e
    (
        "$@" 2>&1 1>&3 3>&- | tee "$logs/err" >&2
        exit "${PIPESTATUS[0]}"
    ) 3>&1 | tee "$logs/out"
    campaign_status=${PIPESTATUS[0]}
    set -e
    campaign=$(sed -n 's/^campaign folder: //p' "$logs/out" | tail -n 1)
    # The per-run lines of the runs that did not end well: `[n/N] <run> : failed (reason)`.
    campaign_failed=$(grep -E '^\[[0-9]+/[0-9]+\] .* : (failed|invalid)' "$logs/err" || true)
}

analyse() {
    local what="$1"
    shift
    step "$what"
    "$@" || broken+=("$what")
}

name_failures() {
    local name="$1"
    if [ -n "$campaign_failed" ]; then
        echo "$name: these runs failed (their rows in $campaign/runs.csv say why; running the same command again runs them again):" >&2
        echo "$campaign_failed" >&2
    elif [ "$campaign_status" != 0 ]; then
        echo "$name: the campaign exited with status $campaign_status (its error is above)" >&2
    fi
    [ "${#broken[@]}" = 0 ] || echo "$name: these steps failed: ${broken[*]}" >&2
    [ "$campaign_status" = 0 ] && [ "${#broken[@]}" = 0 ]
}
