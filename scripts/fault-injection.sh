#!/usr/bin/env bash
# The fault-injection suite (scripts/test.sh runs it after the workspace's tests, with the
# programs they built: target/o3-test/mpm-bench, and target/o3-test/mpm as the solver of
# both optimisation levels). A smoke-sized campaign (the smoke preset, three repetitions:
# 24 runs) is run once uninterrupted as the reference, then
#  1. kills: the same campaign into a fresh folder, its process group (the harness and its
#     solver) killed with SIGKILL at FAULT_KILLS (20) seeded random moments and resumed
#     after each by the same command, then run to its end: its rows must be exactly the
#     reference's (one `ok` row per run key: none lost, none twice; the run keys and
#     statuses compared, not the timings), every row complete;
#  2. a full disk: the same campaign into a tmpfs about half its size: it must stop with an
#     error naming the full disk and a non-zero exit, every row written before it complete
#     (no torn line) and the reference's; then, the tmpfs remounted bigger, the same command
#     must end with exactly the reference's rows;
#  3. a read-only results folder (a read-only tmpfs as the results root; a campaign folder
#     bind-mounted read-only under a writable root): refused up front, with an error saying
#     so, before any run starts (the solver is never started for a run).
# It prints its tally: kills, rows, duplicates, lost, the seed and its time. The kill moments
# are drawn from FAULT_SEED (41 unless set), each in a window of a few runs' time that
# shrinks as the campaign nears its end, so that every resume moves it on and it ends after
# the last kill.
# Needs root (it mounts tmpfs file systems): anywhere else it fails, saying why.
#   scripts/fault-injection.sh [--keep DIR]    # --keep: work in DIR and leave it there
set -euo pipefail
cd "$(dirname "$0")/.."

fail() { echo "fault injection FAILED: $*" >&2; exit 1; }
step() { printf '\n==> fault injection: %s\n' "$*" >&2; }
start=$(date +%s)

bench=$(realpath -e "${MPM_BENCH:-target/o3-test/mpm-bench}") ||
    fail "no mpm-bench at ${MPM_BENCH:-target/o3-test/mpm-bench}: build it (cargo test --workspace --profile o3-test --no-run) or set MPM_BENCH"
solver=$(realpath -e "${MPM_BENCH_SOLVER_O3:-target/o3-test/mpm}") ||
    fail "no solver at ${MPM_BENCH_SOLVER_O3:-target/o3-test/mpm}: build it or set MPM_BENCH_SOLVER_O3"
seed=${FAULT_SEED:-41}
kills_wanted=${FAULT_KILLS:-20}
[[ $seed =~ ^[0-9]+$ ]] || fail "FAULT_SEED must be a whole number, not '$seed'"
[[ $kills_wanted =~ ^[1-9][0-9]*$ ]] || fail "FAULT_KILLS must be a positive whole number, not '$kills_wanted'"
[ "$(id -u)" = 0 ] ||
    fail "it must run as root: it mounts small tmpfs file systems (a disk that fills up, a read-only folder); run it as root (CI does)"

work=""
if [ "${1:-}" = --keep ]; then
    work="$2"
    mkdir -p "$work"
    rm -rf "${work:?}"/*
fi
mounts=()
cleanup() {
    for m in "${mounts[@]}"; do umount "$m" 2>/dev/null || umount -l "$m" 2>/dev/null || true; done
    [ "${keep:-}" = 1 ] || rm -rf "$work"
}
keep=0
if [ -z "$work" ]; then
    work=$(mktemp -d "${TMPDIR:-/tmp}/mpm-fault-injection.XXXXXX")
else
    keep=1
fi
trap cleanup EXIT
work=$(cd "$work" && pwd -P)

# The solver through a wrapper that logs every call, so that step 3 can tell whether a run
# was started; every step uses it (the campaign folders' solver hash stays one).
mkdir -p "$work/bin"
printf '#!/bin/sh\necho "$*" >> "%s"\nexec "%s" "$@"\n' "$work/solver-calls.log" "$solver" > "$work/bin/mpm"
chmod +x "$work/bin/mpm"
export MPM_BENCH_SOLVER_O3="$work/bin/mpm" MPM_BENCH_SOLVER_O0="$work/bin/mpm"
args=(run --preset smoke --reps 3 --no-build --quiet)

# A mount of its own, removed at the end.
mount_tmpfs() {
    mkdir -p "$1"
    mount -t tmpfs -o "size=$2" mpm-fault-injection "$1" ||
        fail "cannot mount a tmpfs at $1 (mount -t tmpfs): this suite needs a machine where root may mount file systems (not an unprivileged container)"
    mounts=("$1" "${mounts[@]}")
}

# rows FILE: the rows of a runs.csv as "run_key status" lines; fails on a torn line or a row
# with another number of cells than the header.
# compare REF GOT: "rows N duplicates D lost L extra E" of GOT against REF (the rows of
# REF: one ok row per key); exit 1 unless GOT holds exactly REF's keys and statuses.
# subset REF GOT: as compare, but GOT may lack rows of REF (none lost is not asked).
# count FILE: the ok rows of a runs.csv that may end in a torn line.
csvcheck() {
    python3 - "$@" <<'EOF'
import collections, csv, io, sys

def rows(path):
    data = open(path, newline='', encoding='utf-8').read()
    if data and not data.endswith('\n'):
        sys.exit(f"{path}: torn last line (no line end after {data[-60:]!r})")
    records = list(csv.reader(io.StringIO(data)))
    if not records:
        sys.exit(f"{path}: no header")
    header = records[0]
    out = []
    for n, r in enumerate(records[1:], start=2):
        if len(r) != len(header):
            sys.exit(f"{path}: record {n} has {len(r)} cells, the header {len(header)}: an incomplete row")
        d = dict(zip(header, r))
        if not d['run_key'] or not d['status']:
            sys.exit(f"{path}: record {n} has no run key or status")
        out.append((d['run_key'], d['status']))
    return out

mode = sys.argv[1]
if mode == 'count':  # ok rows of the complete lines, a torn last line left out
    data = open(sys.argv[2], newline='', encoding='utf-8').read()
    records = list(csv.reader(io.StringIO(data[:data.rfind('\n') + 1])))
    print(sum(1 for r in records[1:] if len(r) == len(records[0]) and dict(zip(records[0], r))['status'] == 'ok'))
    sys.exit(0)
if mode == 'rows':
    for key, status in rows(sys.argv[2]):
        print(key, status)
    sys.exit(0)
ref, got = rows(sys.argv[2]), rows(sys.argv[3])
ok = lambda rs: collections.Counter(k for k, s in rs if s == 'ok')
ref_ok, got_ok = ok(ref), ok(got)
if len(ref_ok) != len(ref) or any(n != 1 for n in ref_ok.values()):
    sys.exit(f"{sys.argv[2]}: the reference is not one ok row per run key: {collections.Counter(s for _, s in ref)}")
duplicates = sum(n - 1 for n in got_ok.values() if n > 1)
lost = sum(1 for k in ref_ok if k not in got_ok)
extra = [f"{k} {s}" for k, s in got if s != 'ok' or k not in ref_ok]
print(f"rows {len(got)} duplicates {duplicates} lost {lost} extra {len(extra)}")
bad = duplicates or extra or (mode == 'compare' and lost)
if bad:
    for k, n in got_ok.items():
        if n > 1:
            print(f"  run key {k}: {n} ok rows", file=sys.stderr)
    for e in extra:
        print(f"  a row not of the reference: {e}", file=sys.stderr)
    if mode == 'compare':
        for k in ref_ok:
            if k not in got_ok:
                print(f"  run key {k}: no ok row (lost)", file=sys.stderr)
sys.exit(1 if bad else 0)
EOF
}

# The one runs.csv under a results root.
csv_in() {
    local found
    found=$(find "$1" -name runs.csv)
    [ "$(printf '%s\n' "$found" | grep -c .)" = 1 ] || fail "expected one campaign folder under $1, found: ${found:-none}"
    printf '%s\n' "$found"
}

# The runs of the solver started so far (its calls with `run`).
solver_runs() { grep -c '^run ' "$work/solver-calls.log" 2>/dev/null || true; }

step "the reference: the campaign uninterrupted (${args[*]})"
t0=$(date +%s%N)
"$bench" "${args[@]}" --out "$work/ref" > /dev/null 2> "$work/ref.log" || { cat "$work/ref.log" >&2; fail "the reference campaign failed"; }
ref_ms=$(( ($(date +%s%N) - t0) / 1000000 ))
ref_csv=$(csv_in "$work/ref")
runs=$(csvcheck rows "$ref_csv" | wc -l)
csvcheck compare "$ref_csv" "$ref_csv" > /dev/null || fail "the reference campaign's rows are not one ok row per run: see $ref_csv"
echo "  $runs runs, every one ok, in $ref_ms ms" >&2

step "1. killed with SIGKILL at $kills_wanted random moments (seed $seed), resumed after each"
# Each moment is a seeded fraction of a window of (1 + 2p) times the reference's time per
# run, p the runs left over the kills left plus two: about p runs are done between two kills
# (a kill during the first loses only that run), so the campaign moves on at every kill and is
# not done before the last one.
per_run_ms=$(( ref_ms / runs ))
mapfile -t fractions < <(python3 -c '
import random, sys
r = random.Random(int(sys.argv[1]))
for _ in range(3 * int(sys.argv[2])):
    print(f"{r.random():.4f}")' "$seed" "$kills_wanted")
ok_rows() {
    local f
    f=$(find "$1" -name runs.csv 2> /dev/null | head -n 1)
    if [ -n "$f" ]; then csvcheck count "$f"; else echo 0; fi
}
kills=0
ended=0
for fraction in "${fractions[@]}"; do
    [ "$kills" -lt "$kills_wanted" ] || break
    moment=$(awk -v f="$fraction" -v r="$per_run_ms" -v left=$(( runs - $(ok_rows "$work/killed") )) \
        -v k=$(( kills_wanted - kills )) 'BEGIN { printf "%.3f", f * r * (1 + 2 * left / (k + 2)) / 1000 }')
    # A session of its own: its process group is the harness's pid, the solver in it.
    setsid "$bench" "${args[@]}" --out "$work/killed" > /dev/null 2>> "$work/killed.log" &
    pid=$!
    sleep "$moment"
    kill -KILL -- "-$pid" 2>/dev/null || true
    rc=0
    wait "$pid" 2> /dev/null || rc=$? # (the shell's "Killed" notice not printed)
    # Nothing of the group may outlive it (the solver dies with the harness).
    for _ in $(seq 100); do kill -0 -- "-$pid" 2>/dev/null || break; sleep 0.05; done
    kill -0 -- "-$pid" 2>/dev/null && fail "a process of the killed harness's group $pid outlived it"
    case $rc in
        137) kills=$((kills + 1)) ;;
        0) ended=$((ended + 1)) ;;
        *) tail -n 20 "$work/killed.log" >&2; fail "a resumed invocation ended with exit status $rc before its kill (its errors above, all in $work/killed.log)" ;;
    esac
done
[ "$kills" = "$kills_wanted" ] ||
    fail "only $kills kill(s) landed: the campaign ended first ($ended invocation(s) ended before their moment)"
# The rows in after the kills (a kill may have torn the last: the resume sets it aside).
in_before=0
for f in $(find "$work/killed" -name runs.csv); do
    in_before=$(csvcheck rows "$f" 2> /dev/null | wc -l) || in_before="(its last line torn)"
done
"$bench" "${args[@]}" --out "$work/killed" > /dev/null 2>> "$work/killed.log" ||
    { tail -n 20 "$work/killed.log" >&2; fail "the resumed campaign failed after the kills"; }
killed_csv=$(csv_in "$work/killed")
tally=$(csvcheck compare "$ref_csv" "$killed_csv") || fail "after $kills kills the rows are not the reference's ($tally): see $killed_csv"
torn=$(find "$work/killed" -name 'runs.csv.torn-*' | wc -l)
echo "  kills $kills (and $ended invocation(s) that ended before their moment), $in_before rows in after them," \
    "then resumed to its end: $tally; torn lines set aside $torn" >&2
kill_tally="kills $kills, $tally"

step "2. a disk that fills up mid-campaign, then space back"
ref_kb=$(du -sk "$work/ref" | cut -f1)
mnt="$work/full"
mount_tmpfs "$mnt" "$(( ref_kb / 2 ))k"
calls=$(solver_runs)
rc=0
"$bench" "${args[@]}" --out "$mnt" > /dev/null 2> "$work/full.log" || rc=$?
[ "$rc" != 0 ] || fail "the campaign on a $(( ref_kb / 2 )) KiB disk ended with exit status 0 (it needs about $ref_kb KiB)"
grep -q 'is full' "$work/full.log" || { cat "$work/full.log" >&2; fail "the campaign on a full disk ended (exit status $rc) without an error naming the full disk"; }
full_csv=$(csv_in "$mnt")
before=$(csvcheck subset "$ref_csv" "$full_csv") || fail "the rows written before the disk filled are not intact ($before): see $full_csv"
written=$(csvcheck rows "$full_csv" | wc -l)
[ "$written" -gt 0 ] && [ "$written" -lt "$runs" ] ||
    fail "the disk was meant to fill mid-campaign, but $written of $runs rows were written"
echo "  exit status $rc after $written of $runs rows ($(( $(solver_runs) - calls )) runs started): $(grep -m1 'is full' "$work/full.log")" >&2
mount -o "remount,size=$(( ref_kb * 4 ))k" "$mnt" || fail "cannot remount $mnt bigger"
"$bench" "${args[@]}" --out "$mnt" > /dev/null 2>> "$work/full.log" ||
    { tail -n 20 "$work/full.log" >&2; fail "the campaign did not resume once space was back"; }
after=$(csvcheck compare "$ref_csv" "$full_csv") || fail "after space was back the rows are not the reference's ($after): see $full_csv"
echo "  resumed with space back: $after" >&2

step "3. a read-only results folder is refused before any run starts"
# A campaign half done, so that a run would be next.
half="$work/half"
cp -a "$work/ref" "$half"
half_csv=$(csv_in "$half")
head -n $(( runs / 2 + 1 )) "$half_csv" > "$half_csv.cut" && mv "$half_csv.cut" "$half_csv"
refused() { # what, log, rc
    [ "$3" != 0 ] || fail "$1: accepted (exit status 0)"
    grep -qiE 'not writable|read-only' "$2" || { cat "$2" >&2; fail "$1: refused without saying the folder is read-only"; }
    [ "$(solver_runs)" = "$calls" ] || fail "$1: refused only after a run had started"
    echo "  $1: exit status $3: $(grep -m1 -iE 'not writable|read-only' "$2")" >&2
}
ro="$work/ro"
mount_tmpfs "$ro" "$(( ref_kb * 2 ))k"
cp -a "$half/." "$ro/"
mount -o remount,ro "$ro" || fail "cannot remount $ro read-only"
calls=$(solver_runs)
rc=0
"$bench" "${args[@]}" --out "$ro" > /dev/null 2> "$work/ro.log" || rc=$?
refused "a read-only results root" "$work/ro.log" "$rc"
dir=$(dirname "$half_csv")
mount --bind "$dir" "$dir" && mounts=("$dir" "${mounts[@]}") && mount -o remount,bind,ro "$dir" ||
    fail "cannot bind-mount $dir read-only"
rc=0
"$bench" "${args[@]}" --out "$half" > /dev/null 2> "$work/ro-folder.log" || rc=$?
refused "a read-only campaign folder under a writable root" "$work/ro-folder.log" "$rc"

secs=$(( $(date +%s) - start ))
printf '\nfault injection passed: %s; full disk: %s rows before it, then %s; read-only refused twice; seed %s (FAULT_SEED); %s s\n' \
    "$kill_tally" "$written" "$after" "$seed" "$secs" >&2
