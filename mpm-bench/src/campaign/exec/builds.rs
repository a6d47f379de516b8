//! The builds `mpm-bench ab` compares: this checkout's (built as `mpm-bench run` builds
//! it), one at a git revision (checked out into a worktree and built into a target folder of
//! its own, so that the two never overwrite each other's binaries), or binaries already
//! built (`DIR/o3/mpm`, `DIR/o0/mpm`, the layout of a Cargo target folder and of a bundle's
//! `bin/`).

use super::solver::{build_solver_in, cargo_profile, sha256_file, Solver};
use crate::campaign::plan::preset::OptLevel;
use anyhow::{bail, Context, Result};
use serde::Serialize;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Instant;

/// A build made for a comparison: where its solvers came from and what it cost.
#[derive(Clone, Debug, Serialize)]
pub struct BuildRecord {
    /// `rev REV (SHA)`, `binaries in DIR`, or `this checkout`.
    pub source: String,
    /// The revision's full commit id, when built from one.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub commit: Option<String>,
    /// Seconds the build took (0 when nothing was built).
    pub build_s: f64,
}

/// The solvers of `opts` found in `dir`: `DIR/<profile>/mpm` with the level's Cargo profile
/// ([`cargo_profile`]), else `DIR/<level>/mpm`, else `DIR/mpm-<level>` as a bundle names them.
pub fn solvers_in(dir: &Path, opts: &[OptLevel]) -> Result<Vec<Solver>> {
    let mut out = Vec::new();
    for &opt in opts {
        let mut candidates = vec![dir.join(cargo_profile(opt)?).join("mpm")];
        candidates.extend([dir.join(opt.as_str()).join("mpm"), dir.join(format!("mpm-{opt}"))]);
        candidates.dedup();
        let Some(path) = candidates.iter().find(|p| p.is_file()) else {
            let looked: Vec<String> = candidates.iter().map(|p| p.display().to_string()).collect();
            bail!(
                "no `mpm` binary of level {opt} in {} (looked for {}): give the folder that holds the \
                 profiles' folders, e.g. a Cargo target folder",
                dir.display(),
                looked.join(" and ")
            );
        };
        let path = path.canonicalize().with_context(|| format!("cannot resolve {}", path.display()))?;
        out.push(Solver { opt, sha256: sha256_file(&path)?, path });
    }
    Ok(out)
}

/// The full commit id of `rev` in the repository at `workspace`.
pub fn resolve_rev(workspace: &Path, rev: &str) -> Result<String> {
    let out = Command::new("git")
        .current_dir(workspace)
        .args(["rev-parse", "--verify", "--quiet", &format!("{rev}^{{commit}}")])
        .output()
        .context("cannot run git (needed for --baseline-rev)")?;
    let sha = String::from_utf8_lossy(&out.stdout).trim().to_string();
    if !out.status.success() || sha.is_empty() {
        bail!(
            "--baseline-rev {rev}: no such commit in {} (in CI, fetch enough history: `git fetch --depth=50 origin \
             <base branch>`, or actions/checkout with fetch-depth: 0)",
            workspace.display()
        );
    }
    Ok(sha)
}

/// Build the solvers of `opts` at `rev` of the repository at `workspace`: a detached worktree
/// of the commit at `target/ab-src-<sha>` (made once, reused), built with
/// `CARGO_TARGET_DIR=target` and `cargo_args` (e.g. `--no-default-features`), its binaries
/// then copied to `target/ab-bin-<sha>/<profile>/mpm`, where no later build overwrites them
/// (so `target` may be this checkout's own, sharing its dependencies' builds).
pub fn build_rev(
    workspace: &Path,
    rev: &str,
    opts: &[OptLevel],
    target: &Path,
    cargo_args: &[String],
    quiet: bool,
) -> Result<(Vec<Solver>, BuildRecord)> {
    let sha = resolve_rev(workspace, rev)?;
    let t0 = Instant::now();
    let src = target.join(format!("ab-src-{}", &sha[..12]));
    if !src.join("Cargo.toml").is_file() {
        std::fs::create_dir_all(target).with_context(|| format!("cannot create {}", target.display()))?;
        // A worktree left by an interrupted run is registered but incomplete: prune first.
        let _ = Command::new("git").current_dir(workspace).args(["worktree", "prune"]).status();
        let status = Command::new("git")
            .current_dir(workspace)
            .args(["worktree", "add", "--detach", "--force"])
            .arg(&src)
            .arg(&sha)
            .stdout(std::process::Stdio::null())
            .status()
            .context("cannot run git worktree add")?;
        if !status.success() {
            bail!("cannot check out {rev} ({sha}) into {} ({status})", src.display());
        }
    }
    for &opt in opts {
        if !quiet {
            eprintln!("building the baseline {rev} ({}) in profile {opt} into {}", &sha[..12], target.display());
        }
        build_solver_in(&src, target, opt, cargo_args, quiet)
            .with_context(|| format!("building the baseline {rev}"))?;
    }
    let solvers = keep_aside(&solvers_in(target, opts)?, &target.join(format!("ab-bin-{}", &sha[..12])))?;
    let record =
        BuildRecord { source: format!("rev {rev} ({sha})"), commit: Some(sha), build_s: t0.elapsed().as_secs_f64() };
    Ok((solvers, record))
}

/// Copy `solvers` to `dir/<profile>/mpm` (replacing what is there); the copies.
pub fn keep_aside(solvers: &[Solver], dir: &Path) -> Result<Vec<Solver>> {
    let mut out = Vec::new();
    for s in solvers {
        let to = dir.join(s.opt.as_str()).join("mpm");
        std::fs::create_dir_all(to.parent().unwrap_or(dir))
            .with_context(|| format!("cannot create {}", dir.display()))?;
        let tmp = to.with_extension("tmp");
        std::fs::copy(&s.path, &tmp)
            .with_context(|| format!("cannot copy {} to {}", s.path.display(), tmp.display()))?;
        std::fs::rename(&tmp, &to).with_context(|| format!("cannot move {} into place", tmp.display()))?;
        out.push(Solver { opt: s.opt, path: to, sha256: s.sha256.clone() });
    }
    Ok(out)
}

/// Where `--baseline-rev` builds by default: `<target>/ab-baseline` of the workspace.
pub fn default_baseline_root(workspace: &Path) -> PathBuf {
    super::solver::target_dir(workspace).join("ab-baseline")
}
