//! Records from what the programs were built, so that every JSON summary of `mpm`, every
//! checkpoint, `mpm --version` and the harness's in-process measurements can say which commit
//! and which compiler produced them (results must name their source).
//!
//! Exports to the crate (read with `env!`):
//! * `MPM_RUSTC`: `rustc -V` of the compiler (`unknown` if it cannot be run);
//! * `MPM_GIT_COMMIT`, `MPM_GIT_COMMIT_SHORT`: `git rev-parse HEAD` of the workspace
//!   (`unknown` without git or outside a repository);
//! * `MPM_GIT_DIRTY`: `true` when `git status --porcelain --untracked-files=no` lists changes,
//!   `false` when not, `unknown` without git.
//!
//! The script runs again when HEAD, the branch ref, the index or any source of the solver
//! (mpm-core, mpm-host, mpm-cli, the Cargo files) changes, so the dirty flag is that of the
//! sources the binary was built from. The build's profile and optimisation level are
//! mpm-cli's (its own build script).

use std::path::{Path, PathBuf};
use std::process::Command;

fn main() {
    println!("cargo:rerun-if-changed=build.rs");
    let rustc = std::env::var("RUSTC").unwrap_or_else(|_| "rustc".into());
    let rustc_v = output(Command::new(rustc).arg("-V")).unwrap_or_else(|| "unknown".into());
    println!("cargo:rustc-env=MPM_RUSTC={rustc_v}");
    git_facts();
}

/// Commit and dirty flag, and the files whose change makes them stale.
fn git_facts() {
    let manifest = PathBuf::from(std::env::var("CARGO_MANIFEST_DIR").unwrap_or_else(|_| ".".into()));
    let ws = manifest.parent().map(Path::to_path_buf).unwrap_or_else(|| manifest.clone());
    let git = |args: &[&str]| output(Command::new("git").arg("-C").arg(&ws).args(args));
    let commit = git(&["rev-parse", "HEAD"]);
    let dirty = commit
        .as_ref()
        .and_then(|_| git(&["status", "--porcelain", "--untracked-files=no"]).or(Some(String::new())))
        .map(|s| (!s.is_empty()).to_string());
    let commit = commit.unwrap_or_else(|| "unknown".into());
    let short: String = if commit == "unknown" { commit.clone() } else { commit.chars().take(12).collect() };
    let dirty = dirty.unwrap_or_else(|| "unknown".into());
    let short = if dirty == "true" { format!("{short}-dirty") } else { short };
    println!("cargo:rustc-env=MPM_GIT_COMMIT={commit}");
    println!("cargo:rustc-env=MPM_GIT_COMMIT_SHORT={short}");
    println!("cargo:rustc-env=MPM_GIT_DIRTY={dirty}");
    // Stale when HEAD moves, the branch moves, the index changes, or a source is edited.
    let mut watch: Vec<PathBuf> = Vec::new();
    for p in ["HEAD", "index", "packed-refs"] {
        if let Some(path) = git(&["rev-parse", "--git-path", p]) {
            watch.push(abs(&ws, &path));
        }
    }
    if let Some(r) = git(&["symbolic-ref", "-q", "HEAD"]) {
        if let Some(path) = git(&["rev-parse", "--git-path", &r]) {
            watch.push(abs(&ws, &path));
        }
    }
    for p in [
        "Cargo.toml",
        "Cargo.lock",
        "mpm-core",
        "mpm-host/src",
        "mpm-host/Cargo.toml",
        "mpm-cli/src",
        "mpm-cli/Cargo.toml",
    ] {
        watch.push(ws.join(p));
    }
    for w in watch.iter().filter(|w| w.exists()) {
        println!("cargo:rerun-if-changed={}", w.display());
    }
}

fn abs(ws: &Path, p: &str) -> PathBuf {
    let p = Path::new(p);
    if p.is_absolute() {
        p.to_path_buf()
    } else {
        ws.join(p)
    }
}

/// Trimmed standard output of a successful command.
fn output(cmd: &mut Command) -> Option<String> {
    cmd.output()
        .ok()
        .filter(|o| o.status.success())
        .map(|o| String::from_utf8_lossy(&o.stdout).trim().to_string())
        .filter(|s| !s.is_empty())
}
