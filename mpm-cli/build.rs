//! Records how `mpm` was built, so that every JSON summary and `mpm --version` can say which
//! optimisation level produced it (the study compares `o3` and `o0` builds). The commit and
//! the compiler are mpm-host's (`mpm_host::identity`).
//!
//! Exports to the crate (read with `env!`):
//! * `MPM_OPT_LEVEL`: Cargo's `OPT_LEVEL` (`0`-`3`, `s`, `z`);
//! * `MPM_PROFILE`: the Cargo profile, parsed from `OUT_DIR`
//!   (`target/[<triple>/]<profile>/build/<pkg>-<hash>/out`; `debug` for `dev` and `test`);
//! * `MPM_DEBUG_ASSERTIONS`: whether `debug_assertions` is on;
//! * `MPM_TARGET`: the target triple.

use std::path::Path;

fn main() {
    let opt = std::env::var("OPT_LEVEL").unwrap_or_else(|_| "unknown".into());
    let out = std::env::var("OUT_DIR").unwrap_or_default();
    let profile = Path::new(&out)
        .ancestors()
        .nth(3)
        .and_then(|p| p.file_name())
        .and_then(|s| s.to_str())
        .unwrap_or("unknown")
        .to_string();
    let debug_assertions = std::env::var_os("CARGO_CFG_DEBUG_ASSERTIONS").is_some();
    let target = std::env::var("TARGET").unwrap_or_else(|_| "unknown".into());
    println!("cargo:rustc-env=MPM_OPT_LEVEL={opt}");
    println!("cargo:rustc-env=MPM_PROFILE={profile}");
    println!("cargo:rustc-env=MPM_DEBUG_ASSERTIONS={debug_assertions}");
    println!("cargo:rustc-env=MPM_TARGET={target}");
    println!("cargo:rerun-if-changed=build.rs");
}
