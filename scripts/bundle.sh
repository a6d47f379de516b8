#!/usr/bin/env bash
# Make one self-contained archive of the harness, for a borrowed machine with no Rust
# toolchain and no hwloc (a cloud VM, a cluster node on a short reservation): `mpm` at both
# optimisation levels, `mpm-bench`, the presets, the shared libraries they load beyond the C
# runtime, and the one-command many-core campaign.
#
#   scripts/bundle.sh                        # -> target/bundle/mpm-bench-<version>-x86_64-linux.tar.gz
#   scripts/bundle.sh --mpi                  # `mpm` with MPI: the machine then needs its own Open MPI
#   scripts/bundle.sh --o3-profile o3-test --out DIR   # no LTO link (the bundle test)
#   scripts/bundle.sh --mpm-bench FILE       # take this mpm-bench (built with this workspace's
#                                            # build.rs) instead of building one
#
# On the borrowed machine:
#   tar xzf mpm-bench-<version>-x86_64-linux.tar.gz
#   cd mpm-bench-<version>-x86_64-linux && ./manycore.sh
#
# The unpacked bundle:
#   bin/mpm-bench, bin/mpm   wrappers (POSIX sh): point the harness at the bundle's solvers
#                            (MPM_BENCH_SOLVER_O3 / _O0) and presets (MPM_BENCH_WORKSPACE), and
#                            hwloc at an empty plugin folder, so that a host's hwloc plugins
#                            of another version are never loaded into the bundle's hwloc
#   libexec/mpm-bench, libexec/o3/mpm, libexec/o0/mpm   the programs themselves
#   lib/                     every shared library they load beyond the C runtime (hwloc, udev),
#                            found through mpm-bench's run path $ORIGIN/../lib (mpm-bench/build.rs),
#                            so no LD_LIBRARY_PATH leaks into the programs the harness starts
#   configs/                 the presets; manycore.sh (with campaign-steps.sh, its shared steps);
#                            README.txt
#   bundle.toml              what was built, from which commit, with which compiler and Cargo
#                            profiles, and the oldest glibc it runs on (campaign manifests record it)
# The SIMD kernels are chosen at run time (AVX-512, AVX2 or scalar): one build serves every
# x86-64 machine. The programs are built in the workspace's target folder, reusing what is
# built there; the `mpm` without MPI that the bundle takes is put back as it was.
set -euo pipefail
cd "$(dirname "$0")/.."
. scripts/c-runtime.sh

o3_profile=o3
bench=""
mpi=0
out=target/bundle
while [ $# -gt 0 ]; do
    case "$1" in
        --mpi) mpi=1; shift ;;
        --o3-profile) o3_profile="$2"; shift 2 ;;
        --mpm-bench) bench="$2"; shift 2 ;;
        --out) out="$2"; shift 2 ;;
        -h|--help) sed -n '2,31p' "$0" | sed 's/^# \{0,1\}//'; exit 0 ;;
        *) echo "bundle.sh: unknown option '$1' (see --help)" >&2; exit 2 ;;
    esac
done
case "$(uname -s)-$(uname -m)" in
    Linux-x86_64) ;;
    *) echo "bundle.sh: bundles are made on and for x86_64 Linux; this is $(uname -s) $(uname -m)" >&2; exit 2 ;;
esac
[ -f "$HOME/.cargo/env" ] && . "$HOME/.cargo/env"

version=$(sed -n '/^\[workspace.package\]/,/^\[/s/^version = "\(.*\)"/\1/p' Cargo.toml)
name="mpm-bench-$version-x86_64-linux"
features=(--no-default-features)
[ "$mpi" = 1 ] && features=(--features mpi)
target=$(cargo metadata --format-version 1 --no-deps | sed 's/.*"target_directory":"\([^"]*\)".*/\1/')
step() { printf '\n==> %s\n' "$*" >&2; }

mkdir -p "$out"
stage=$(mktemp -d "$out/.stage.XXXXXX")
trap 'rm -rf "$stage"' EXIT
root="$stage/$name"
mkdir -p "$root/bin" "$root/libexec/o3" "$root/libexec/o0" "$root/lib/hwloc" "$root/configs"

# build_mpm PROFILE DEST: `mpm` (features as asked) into DEST. Without MPI it replaces the
# default `mpm` in target/PROFILE/, which the hybrid campaigns need: that one is put back.
build_mpm() {
    local bin="$target/$1/mpm" saved="$target/$1/.mpm.before-bundle"
    [ "$mpi" = 0 ] && [ -f "$bin" ] && ln -f "$bin" "$saved"
    cargo build --profile "$1" -p mpm-cli --bin mpm "${features[@]}"
    install -m 755 "$bin" "$2"
    if [ "$mpi" = 0 ]; then
        if [ -f "$saved" ]; then mv -f "$saved" "$bin"; else rm -f "$bin"; fi
    fi
}
step "building mpm ($o3_profile as o3, and o0; ${features[*]})${bench:+; mpm-bench: $bench}"
build_mpm "$o3_profile" "$root/libexec/o3/mpm"
build_mpm o0 "$root/libexec/o0/mpm"
if [ -z "$bench" ]; then
    step "building mpm-bench ($o3_profile)"
    cargo build --profile "$o3_profile" -p mpm-bench --bin mpm-bench
    bench="$target/$o3_profile/mpm-bench"
fi
install -m 755 "$bench" "$root/libexec/mpm-bench"
cp configs/*.toml "$root/configs/"
install -m 755 scripts/manycore.sh "$root/manycore.sh"
# The steps manycore.sh shares with scripts/reproduce.sh, sourced from beside it.
install -m 644 scripts/campaign-steps.sh "$root/campaign-steps.sh"

# mpm-bench's libraries beyond the C runtime go into lib/. `mpm` needs none without MPI;
# with MPI it needs the machine's own Open MPI (its libraries, plugins and mpirun go
# together), so those are named in bundle.toml, not carried.
step "collecting shared libraries"
collect() { # collect EXE: the non-C-runtime libraries of EXE, "soname path" per line
    ldd "$1" | while read -r soname arrow path _; do
        if [ "$arrow" = "=>" ] && ! is_c_runtime "$soname"; then echo "$soname $path"; fi
    done
}
toml_list() { sed 's/.*/"&"/' | paste -sd, - | sed 's/,/, /g'; } # lines -> "a", "b"
while read -r soname path; do
    if [ "$path" = "not" ]; then
        echo "bundle.sh: mpm-bench needs $soname, which this machine does not have (scripts/bootstrap.sh installs it)" >&2
        exit 1
    fi
    cp -L "$path" "$root/lib/$soname"
    chmod 644 "$root/lib/$soname"
done < <(collect "$root/libexec/mpm-bench")
libraries=$(find "$root/lib" -maxdepth 1 -name '*.so*' -printf '%f\n' | sort | toml_list)
host_libraries=$(collect "$root/libexec/o3/mpm" | cut -d' ' -f1 | toml_list)

# The oldest glibc the bundle runs on: the newest GLIBC_x.y symbol version any part needs.
glibc=$(for f in "$root"/libexec/mpm-bench "$root"/libexec/*/mpm "$root"/lib/*.so*; do
            objdump -T "$f" 2>/dev/null | grep -o 'GLIBC_[0-9][0-9.]*' || true
        done | sed 's/GLIBC_//' | sort -uV | tail -n 1)

for prog in mpm-bench mpm; do
    exe='$root/libexec/mpm-bench'
    [ "$prog" = mpm ] && exe='$root/libexec/o3/mpm'
    cat > "$root/bin/$prog" <<EOF
#!/bin/sh
# $prog from the bundle: the harness pointed at the bundle's solvers and presets (each can
# be overridden), hwloc at the bundle's empty plugin folder (never a host's plugins).
root=\$(CDPATH= cd -- "\$(dirname -- "\$0")/.." && pwd)
HWLOC_PLUGINS_PATH="\$root/lib/hwloc"
MPM_BENCH_SOLVER_O3="\${MPM_BENCH_SOLVER_O3:-\$root/libexec/o3/mpm}"
MPM_BENCH_SOLVER_O0="\${MPM_BENCH_SOLVER_O0:-\$root/libexec/o0/mpm}"
MPM_BENCH_WORKSPACE="\${MPM_BENCH_WORKSPACE:-\$root}"
export HWLOC_PLUGINS_PATH MPM_BENCH_SOLVER_O3 MPM_BENCH_SOLVER_O0 MPM_BENCH_WORKSPACE
exec "$exe" "\$@"
EOF
    chmod 755 "$root/bin/$prog"
done

commit=$(git rev-parse HEAD 2>/dev/null || echo unknown)
dirty=$(git status --porcelain --untracked-files=no 2>/dev/null | grep -q . && echo true || echo false)
rustc=$(rustc -vV | sed -n '1p;s/^host: //p' | paste -sd'|' - | sed 's/|\(.*\)/ (host \1)/')
{
    cat <<EOF
# What this bundle was built from (scripts/bundle.sh). mpm-bench reads it: a campaign run
# from the bundle records this commit, compiler and Cargo profiles in its manifest.
name = "$name"
version = "$version"
commit = "$commit"
dirty = $dirty
rustc = "$rustc"
# The oldest glibc the programs and libraries run on.
glibc = "$glibc"
mpi = $( [ "$mpi" = 1 ] && echo true || echo false )
# The Cargo profile of libexec/o3/mpm and libexec/mpm-bench (o3, or o3-test for the test).
o3_profile = "$o3_profile"
# Carried in lib/.
libraries = [$libraries]
# Needed by mpm and taken from the machine (with MPI: its Open MPI).
host_libraries = [$host_libraries]

# The workspace's Cargo profiles at the build.
EOF
    awk '/^\[/ { keep = ($0 ~ /^\[profile\./) } keep' Cargo.toml
} > "$root/bundle.toml"

cat > "$root/README.txt" <<EOF
$name: the MPM benchmark harness for a machine without a Rust toolchain
(x86-64 Linux, glibc $glibc or newer). What it was built from: bundle.toml.

The many-core campaign, its figures, claims and report in one archive:  ./manycore.sh
Its plan and estimated duration only:                                    ./manycore.sh --dry-run
Any campaign:        bin/mpm-bench run --preset smoke --out results
One simulation:      bin/mpm run taylor --model 1 --threads 2 --strategy dd
Where workers go:    bin/mpm-bench topology
EOF

archive="$out/$name.tar.gz"
tar -C "$stage" --sort=name --owner=0 --group=0 --numeric-owner -czf "$archive.part" "$name"
mv "$archive.part" "$archive"
step "bundle: $archive ($(du -h "$archive" | cut -f1); glibc >= $glibc; lib/: ${libraries:-none})"
echo "$archive"
