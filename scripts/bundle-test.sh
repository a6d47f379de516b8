#!/usr/bin/env bash
# The bundle test (scripts/test.sh runs it after the workspace's tests, whose builds it
# reuses): make the bundle at profile o3-test (o3 without its LTO link), unpack it, and check
#  1. every library its programs load resolves inside the bundle or to the C runtime (ldd);
#  2. from the unpacked bundle, with neither cargo nor rustc on the PATH and nothing of the
#     workspace in the environment, ./manycore.sh --preset smoke runs the smoke campaign
#     (every row ok, from the bundle's own solvers, the bundle's commit in the manifest) and
#     its bandwidth, figures, claims and report, and packs the campaign into one archive of
#     at most 16 MiB holding them;
#  3. the manycore preset's dry run from the bundle, capped to this machine's cores: the
#     thread counts above them are skipped and said, none is planned oversubscribed; and its
#     estimate as on 16 cores (--assume-cores 16), printed for the record.
# A shell script rather than a Rust test: it builds with cargo (not from inside `cargo
# test`), needs a PATH without the toolchain, and checks the bundle as a user unpacks it.
#   scripts/bundle-test.sh [--keep DIR]    # --keep: work in DIR and leave it there
set -euo pipefail
cd "$(dirname "$0")/.."
. scripts/c-runtime.sh
[ -f "$HOME/.cargo/env" ] && . "$HOME/.cargo/env"

work=""
if [ "${1:-}" = --keep ]; then
    work="$2"
    mkdir -p "$work"
fi
if [ -z "$work" ]; then
    work=$(mktemp -d "${TMPDIR:-/tmp}/mpm-bundle-test.XXXXXX")
    trap 'rm -rf "$work"' EXIT
fi
work=$(cd "$work" && pwd -P)
rm -rf "$work/results" "$work/dry" # a kept folder's earlier campaign would be resumed, not run
start=$(date +%s)
step() { printf '\n==> bundle test: %s\n' "$*" >&2; }
fail() { echo "bundle test FAILED: $*" >&2; exit 1; }

# mpm-bench as the workspace's tests build it: after scripts/test.sh's `cargo test` this
# builds nothing (a build of mpm-bench alone would unify its dependencies' features
# differently and build them all again); run alone, it builds what is missing.
step "making the bundle (profile o3-test; mpm-bench from the tests' build)"
cargo test --workspace --profile o3-test --no-run --quiet
archive=$(scripts/bundle.sh --o3-profile o3-test --mpm-bench target/o3-test/mpm-bench --out "$work/out" | tail -n 1)
rm -rf "$work/unpacked" && mkdir -p "$work/unpacked"
tar -C "$work/unpacked" -xzf "$archive"
root="$work/unpacked/$(basename "$archive" .tar.gz)"
[ -x "$root/manycore.sh" ] && [ -x "$root/bin/mpm-bench" ] || fail "$archive lacks manycore.sh or bin/mpm-bench"

step "1. the libraries of the bundled programs"
for exe in "$root/libexec/mpm-bench" "$root"/libexec/*/mpm; do
    while read -r soname arrow path _; do
        [ "$arrow" = "=>" ] || continue
        is_c_runtime "$soname" && continue
        # The run path resolves to libexec/../lib/...: compared as the file it names.
        real=$(realpath -e -- "$path" 2>/dev/null) || fail "${exe#"$root"/} needs $soname: not found ($path)"
        case "$real" in
            "$root"/lib/*) echo "  ${exe#"$root"/}: $soname -> ${real#"$root"/}" ;;
            *) fail "${exe#"$root"/} loads $soname from $real, outside the bundle" ;;
        esac
    done < <(ldd "$exe")
done

# The PATH of a machine without the toolchain: this one's, less every folder with cargo or rustc.
bare=$(printf '%s' "$PATH" | tr ':' '\n' | while read -r d; do
    [ -n "$d" ] && [ ! -x "$d/cargo" ] && [ ! -x "$d/rustc" ] && printf '%s:' "$d"
done)
bare=${bare%:}
mkdir -p "$work/home"
borrowed() { (cd "$work" && env -i HOME="$work/home" PATH="$bare" LANG=C.UTF-8 TERM=dumb "$@"); }
borrowed sh -c '! command -v cargo && ! command -v rustc' >/dev/null || fail "cargo or rustc is still on the PATH"

step "2. ./manycore.sh --preset smoke from the unpacked bundle, without cargo or rustc"
borrowed "$root/manycore.sh" --preset smoke --out "$work/results" > "$work/manycore.out" ||
    fail "manycore.sh --preset smoke exited with status $? (output above)"
packed=$(tail -n 1 "$work/manycore.out")
campaign=$(sed -n 's/^campaign folder: //p' "$work/manycore.out" | tail -n 1)
[ -f "$campaign/runs.csv" ] || fail "no runs.csv in the campaign folder '$campaign'"
python3 - "$campaign" "$root" <<'EOF' || fail "the smoke campaign's rows or manifest (above)"
import csv, hashlib, json, sys, tomllib
campaign, root = sys.argv[1], sys.argv[2]
rows = list(csv.DictReader(open(f"{campaign}/runs.csv")))
bad = [(r["run_id"], r["status"], r["reason"]) for r in rows if r["status"] != "ok"]
assert len(rows) == 8 and not bad, f"{len(rows)} rows (8 expected); not ok: {bad}"
bundle = tomllib.load(open(f"{root}/bundle.toml", "rb"))
for opt in ("o3", "o0"):
    sha = hashlib.sha256(open(f"{root}/libexec/{opt}/mpm", "rb").read()).hexdigest()[:16]
    hashes = {r["binary_sha256"] for r in rows if r["opt"] == opt}
    assert hashes == {sha}, f"{opt} rows ran {hashes}, not the bundle's {opt} mpm {sha}"
assert {r["git_commit"] for r in rows} == {bundle["commit"]}, "the rows' commit is not the bundle's"
software = json.load(open(f"{campaign}/manifest.json"))["software"]
assert software["git"]["commit"] == bundle["commit"], software["git"]
assert software["rustc"] == bundle["rustc"] and software["cargo_profiles"].get("o3"), software["rustc"]
print(f"  {len(rows)} rows ok, run by the bundle's solvers; manifest: commit {bundle['commit'][:12]}, {software['rustc']}")
EOF
[ -f "$packed" ] || fail "manycore.sh named no archive (its last line: '$packed')"
size=$(stat -c %s "$packed")
[ "$size" -le $((16 * 1024 * 1024)) ] || fail "$packed is $size bytes, over the 16 MiB limit"
listing=$(tar -tzf "$packed")
for want in runs.csv manifest.json topology.xml bandwidth.json claims.md figures/ report/index.html json/; do
    grep -q "^$(basename "$campaign")/$want" <<<"$listing" || fail "$packed lacks $want"
done
echo "  archive $(basename "$packed"): $((size / 1024)) KiB (limit 16384 KiB), $(wc -l <<<"$listing") entries"

step "3. the manycore preset's dry run from the bundle, capped to this machine's cores"
cores=$(borrowed "$root/bin/mpm-bench" topology | sed -n 's/^Summary .* \([0-9][0-9]*\) core(s), .*/\1/p')
dry=$(borrowed "$root/bin/mpm-bench" run --preset manycore --dry-run --out "$work/dry" 2>&1) ||
    fail "the dry run failed: $dry"
above=$(for t in 1 2 4 8 16; do if [ "$t" -gt "$cores" ]; then printf "%s/" "$t"; fi; done)
above=${above%/}
if [ -n "$above" ]; then
    grep -q "^note: $cores usable core(s) here: the runs of $above threads are skipped, not run oversubscribed" <<<"$dry" ||
        fail "the dry run does not say that $above threads are skipped on $cores cores: $dry"
fi
grep -q oversubscribed <<<"$(grep ' thr pin ' <<<"$dry")" && fail "a run is planned oversubscribed: $dry"
planned=$(grep -o ' [0-9]* thr pin ' <<<"$dry" | awk '{ print $1 }' | sort -un | paste -sd/ -)
for t in ${planned//\// }; do
    [ "$t" -le "$cores" ] || fail "$t threads planned on $cores cores: $dry"
done
echo "  $cores cores: threads $planned planned, ${above:-none} skipped ($(grep -c ' thr pin ' <<<"$dry") runs)"
estimate=$(borrowed "$root/bin/mpm-bench" run --preset manycore --dry-run --assume-cores 16 --out "$work/dry" 2>&1 |
    grep '^estimated duration') || fail "no estimate from --dry-run --assume-cores 16"
echo "  as on 16 cores: $estimate"

step "passed in $(( $(date +%s) - start )) s"
