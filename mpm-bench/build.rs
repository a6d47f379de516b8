//! The `mpm-bench` binary looks for shared libraries in `../lib` beside its own folder first:
//! in the self-contained bundle (`scripts/bundle.sh`) the program is `libexec/mpm-bench` and
//! the libraries it needs beyond the C library (hwloc, udev) are in `lib/`, so it runs on a
//! machine that has none of them installed, started by any means (the bundle's wrapper, a
//! Slurm job, by hand), without `LD_LIBRARY_PATH`, which every child would inherit. The run
//! path is `DT_RPATH` (`--disable-new-dtags`), which the loader also applies to the
//! libraries' own dependencies (libudev for libhwloc); `DT_RUNPATH` would not. In a Cargo
//! target folder `../lib` does not exist and the system's libraries are found as usual.
fn main() {
    println!("cargo:rerun-if-changed=build.rs");
    if std::env::var("CARGO_CFG_TARGET_OS").as_deref() == Ok("linux") {
        println!("cargo:rustc-link-arg-bins=-Wl,--disable-new-dtags,-rpath,$ORIGIN/../lib");
    }
}
