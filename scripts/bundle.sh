#!/usr/bin/env bash
# Make one self-contained archive of the harness, for a borrowed machine with no Rust
# toolchain and no hwloc development files (a cloud VM, a cluster node on a short
# reservation): `mpm` at both optimisation levels, `mpm-bench`, the presets, the shared
# libraries they load beyond the C library, and the one-command many-core campaign.
#
#   scripts/bundle.sh                 # -> target/bundle/mpm-bench-<version>-x86_64-linux.tar.gz
#   scripts/bundle.sh --mpi           # `mpm` with MPI (the target needs a matching mpirun)
#   scripts/bundle.sh --o3-profile o3-test --out DIR   # what scripts/test.sh does (no LTO link)
#
# On the borrowed machine:
#   tar xzf mpm-bench-<version>-x86_64-linux.tar.gz
#   cd mpm-bench-<version>-x86_64-linux && ./manycore.sh
#
# Layout of the unpacked bundle:
#   bin/mpm-bench, bin/mpm    wrappers: point the loader at lib/ and the harness at its
#                             solvers (MPM_BENCH_SOLVER_O3 / _O0) and presets (configs/)
#   libexec/mpm-bench, libexec/o3/mpm, libexec/o0/mpm   the programs themselves
#   lib/                      every shared library they load that is not part of the C
#                             library (hwloc and what it needs), with an empty hwloc plugin
#                             folder so that the host's hwloc plugins are never mixed in
#   configs/                  the presets; manycore.sh; BUNDLE.txt (what was built, from what,
#                             and the oldest glibc it runs on)
# The SIMD kernels are chosen at run time (AVX-512, AVX2 or scalar), so one build serves
# every x86-64 machine. The wrappers are POSIX sh and use only the C library's loader.
set -euo pipefail
cd "$(dirname "$0")/.."

o3_profile=o3
mpi=0
out=target/bundle
build=1
while [ $# -gt 0 ]; do
    case "$1" in
        --mpi) mpi=1; shift ;;
        --o3-profile) o3_profile="$2"; shift 2 ;;
        --out) out="$2"; shift 2 ;;
        --no-build) build=0; shift ;;
        -h|--help) sed -n '2,27p' "$0" | sed 's/^# \{0,1\}//'; exit 0 ;;
        *) echo "bundle.sh: unknown option '$1' (see --help)" >&2; exit 2 ;;
    esac
done
case "$(uname -m)" in
    x86_64) ;;
    *) echo "bundle.sh: bundles are made for x86_64 Linux; this machine is $(uname -m)" >&2; exit 2 ;;
esac
[ -f "$HOME/.cargo/env" ] && . "$HOME/.cargo/env"

version=$(sed -n '/^\[workspace.package\]/,/^\[/s/^version = "\(.*\)"/\1/p' Cargo.toml)
name="mpm-bench-$version-x86_64-linux"
# Its own target folder: the bundle's `mpm` is built without the `mpi` feature, which must not
# replace the default build in target/<profile>/ that the hybrid campaigns and tests use.
tdir="${BUNDLE_TARGET_DIR:-target/bundle-build}"
features=(--no-default-features)
[ "$mpi" = 1 ] && features=(--features mpi)

step() { printf '\n==> %s\n' "$*" >&2; }
if [ "$build" = 1 ]; then
    step "building mpm ($o3_profile and o0, ${features[*]}) and mpm-bench ($o3_profile) into $tdir"
    CARGO_TARGET_DIR="$tdir" cargo build --profile "$o3_profile" -p mpm-cli --bin mpm "${features[@]}"
    CARGO_TARGET_DIR="$tdir" cargo build --profile o0 -p mpm-cli --bin mpm "${features[@]}"
    CARGO_TARGET_DIR="$tdir" cargo build --profile "$o3_profile" -p mpm-bench --bin mpm-bench
fi

mkdir -p "$out"
stage=$(mktemp -d "$out/.stage.XXXXXX")
trap 'rm -rf "$stage"' EXIT
root="$stage/$name"
mkdir -p "$root/bin" "$root/libexec/o3" "$root/libexec/o0" "$root/lib/hwloc" "$root/configs"
install -m 755 "$tdir/$o3_profile/mpm" "$root/libexec/o3/mpm"
install -m 755 "$tdir/o0/mpm" "$root/libexec/o0/mpm"
install -m 755 "$tdir/$o3_profile/mpm-bench" "$root/libexec/mpm-bench"
cp configs/*.toml "$root/configs/"
install -m 755 scripts/manycore.sh "$root/manycore.sh"

# The C library's own objects: every Linux machine has them, and they must come from the
# machine (the loader and libc go together). Everything else a program loads is bundled.
is_libc() {
    case "$1" in
        linux-vdso.so.*|ld-linux*.so.*|libc.so.*|libm.so.*|libpthread.so.*|libdl.so.*|librt.so.*|\
        libresolv.so.*|libutil.so.*|libanl.so.*|libmvec.so.*|libnsl.so.*|libBrokenLocale.so.*) return 0 ;;
        *) return 1 ;;
    esac
}
step "collecting shared libraries"
for exe in "$root/libexec/mpm-bench" "$root/libexec/o3/mpm" "$root/libexec/o0/mpm"; do
    while read -r soname arrow path _; do
        [ "$arrow" = "=>" ] || continue
        is_libc "$soname" && continue
        if [ "$path" = "not" ]; then
            echo "bundle.sh: $(basename "$exe") needs $soname, which this machine does not have" >&2
            exit 1
        fi
        [ -e "$root/lib/$soname" ] || cp -L "$path" "$root/lib/$soname"
    done < <(ldd "$exe")
done
chmod 644 "$root/lib/"*.so*

# The oldest glibc the bundle runs on: the newest GLIBC_x.y symbol version any of it needs.
glibc=$(for f in "$root"/libexec/mpm-bench "$root"/libexec/*/mpm "$root"/lib/*.so*; do
            objdump -T "$f" 2>/dev/null | grep -o 'GLIBC_[0-9][0-9.]*' || true
        done | sed 's/GLIBC_//' | sort -uV | tail -n 1)

for prog in mpm-bench mpm; do
    target='$root/libexec/mpm-bench'
    [ "$prog" = mpm ] && target='$root/libexec/o3/mpm'
    cat > "$root/bin/$prog" <<EOF
#!/bin/sh
# $prog from the bundle: the bundle's libraries first, the host's hwloc plugins never, and
# the harness pointed at the bundle's solvers and presets (each can be overridden).
root=\$(CDPATH= cd -- "\$(dirname -- "\$0")/.." && pwd)
LD_LIBRARY_PATH="\$root/lib\${LD_LIBRARY_PATH:+:\$LD_LIBRARY_PATH}"
HWLOC_PLUGINS_PATH="\$root/lib/hwloc"
MPM_BENCH_SOLVER_O3="\${MPM_BENCH_SOLVER_O3:-\$root/libexec/o3/mpm}"
MPM_BENCH_SOLVER_O0="\${MPM_BENCH_SOLVER_O0:-\$root/libexec/o0/mpm}"
MPM_BENCH_WORKSPACE="\${MPM_BENCH_WORKSPACE:-\$root}"
export LD_LIBRARY_PATH HWLOC_PLUGINS_PATH MPM_BENCH_SOLVER_O3 MPM_BENCH_SOLVER_O0 MPM_BENCH_WORKSPACE
exec "$target" "\$@"
EOF
    chmod 755 "$root/bin/$prog"
done

commit=$(git rev-parse HEAD 2>/dev/null || echo unknown)
dirty=$(git status --porcelain --untracked-files=no 2>/dev/null | grep -q . && echo true || echo false)
cat > "$root/BUNDLE.txt" <<EOF
$name
commit: $commit (dirty: $dirty)
rustc: $(rustc -V 2>/dev/null || echo unknown)
mpm: profiles $o3_profile (as o3) and o0, features: ${features[*]}
mpm-bench: profile $o3_profile
libraries: $(cd "$root/lib" && ls *.so* | tr '\n' ' ')
needs: x86-64 Linux with glibc >= $glibc

Run the many-core campaign:  ./manycore.sh          (./manycore.sh --help)
Or any campaign:             bin/mpm-bench run --preset smoke --out results
One simulation:              bin/mpm run taylor --model 1 --threads 2 --strategy dd
EOF

archive="$out/$name.tar.gz"
tar -C "$stage" -czf "$archive.part" "$name"
mv "$archive.part" "$archive"
step "bundle: $archive ($(du -h "$archive" | cut -f1); needs glibc >= $glibc)"
echo "$archive"
