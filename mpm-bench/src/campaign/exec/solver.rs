//! The solver binaries, in one place: build (`cargo build --profile <profile> -p mpm-cli --bin
//! mpm`), locate (`target/<profile>/mpm`, or `MPM_BENCH_SOLVER_O3` / `MPM_BENCH_SOLVER_O0`)
//! and hash (SHA-256, recorded in the manifest and, abbreviated, in every row).
//!
//! The Cargo profile of a level is the level's name (`o3`, `o0`), or the profile
//! `MPM_BENCH_CARGO_PROFILE_O3` / `MPM_BENCH_CARGO_PROFILE_O0` names ([`cargo_profile`]): another
//! profile of the same optimisation level, e.g. `o3-test` (o3 without link-time optimisation),
//! which `scripts/test.sh` gives its tests so that the campaigns they build reuse the tests' own
//! build instead of building o3 with LTO from scratch. The manifest records the variable (its
//! `env`) and every row the binary's hash.

use crate::campaign::plan::preset::OptLevel;
use crate::campaign::store::manifest::BinaryInfo;
use anyhow::{anyhow, bail, Context, Result};
use std::path::{Path, PathBuf};
use std::process::Command;

/// A solver binary of one optimisation level.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Solver {
    /// Optimisation level.
    pub opt: OptLevel,
    /// Path.
    pub path: PathBuf,
    /// SHA-256, hex.
    pub sha256: String,
}

impl Solver {
    /// Manifest entry.
    pub fn info(&self) -> BinaryInfo {
        BinaryInfo {
            opt_level: self.opt.to_string(),
            path: self.path.display().to_string(),
            sha256: self.sha256.clone(),
        }
    }
}

/// The workspace root: `MPM_BENCH_WORKSPACE`, else the nearest ancestor of this executable
/// or of the current directory with a `[workspace]` Cargo.toml, else the one this harness
/// was compiled in (if it still exists).
pub fn workspace_root() -> Option<PathBuf> {
    if let Ok(w) = std::env::var("MPM_BENCH_WORKSPACE") {
        return Some(PathBuf::from(w));
    }
    let is_ws = |d: &Path| std::fs::read_to_string(d.join("Cargo.toml")).is_ok_and(|t| t.contains("[workspace]"));
    let mut starts: Vec<PathBuf> = Vec::new();
    if let Ok(exe) = std::env::current_exe() {
        starts.push(exe);
    }
    if let Ok(cwd) = std::env::current_dir() {
        starts.push(cwd);
    }
    for s in starts {
        if let Some(d) = s.ancestors().find(|d| is_ws(d)) {
            return Some(d.to_path_buf());
        }
    }
    let compiled = Path::new(env!("CARGO_MANIFEST_DIR")).parent()?;
    is_ws(compiled).then(|| compiled.to_path_buf())
}

/// Cargo's target directory for `workspace`.
pub fn target_dir(workspace: &Path) -> PathBuf {
    match std::env::var_os("CARGO_TARGET_DIR") {
        Some(d) => {
            let d = PathBuf::from(d);
            if d.is_absolute() {
                d
            } else {
                workspace.join(d)
            }
        }
        None => workspace.join("target"),
    }
}

/// SHA-256 of a file, hex.
pub fn sha256_file(path: &Path) -> Result<String> {
    mpm_host::identity::sha256_file(path).with_context(|| format!("cannot hash {}", path.display()))
}

/// The Cargo profile that builds the solver of `opt`: `MPM_BENCH_CARGO_PROFILE_<OPT>` when set,
/// else the level's own profile. An error names the variable when its value cannot be a
/// profile name.
pub fn cargo_profile(opt: OptLevel) -> Result<String> {
    let key = format!("MPM_BENCH_CARGO_PROFILE_{}", opt.as_str().to_ascii_uppercase());
    match std::env::var(&key) {
        Err(std::env::VarError::NotPresent) => Ok(opt.as_str().to_string()),
        Ok(p) if !p.is_empty() && p.chars().all(|c| c.is_ascii_alphanumeric() || c == '-' || c == '_') => Ok(p),
        Ok(p) => bail!(
            "{key}={p:?} is not a Cargo profile name (letters, digits, '-' and '_'): name a profile of \
             Cargo.toml, e.g. {key}=o3-test, or unset it"
        ),
        Err(e) => bail!("{key} is not valid text ({e}): unset it"),
    }
}

/// Build (when `build`) and locate the `mpm` binary of each level in `opts`.
pub fn prepare_solvers(opts: &[OptLevel], build: bool, quiet: bool) -> Result<Vec<Solver>> {
    let ws = workspace_root();
    let mut out = Vec::new();
    for &opt in opts {
        let env_key = format!("MPM_BENCH_SOLVER_{}", opt.as_str().to_ascii_uppercase());
        let path = if let Some(p) = std::env::var_os(&env_key) {
            PathBuf::from(p)
        } else {
            let ws = ws.as_deref().ok_or_else(|| {
                anyhow!(
                    "cannot find the workspace to build or locate the `mpm` solver; run from the \
                     repository, set MPM_BENCH_WORKSPACE, or point {env_key} at a binary"
                )
            })?;
            let path = target_dir(ws).join(cargo_profile(opt)?).join("mpm");
            if build {
                build_solver(ws, opt, quiet)?;
            }
            path
        };
        if !path.is_file() {
            bail!(
                "solver binary {} not found (build it with `cargo build --profile {} -p mpm-cli --bin mpm`)",
                path.display(),
                cargo_profile(opt)?
            );
        }
        let sha256 = sha256_file(&path)?;
        out.push(Solver { opt, path, sha256 });
    }
    Ok(out)
}

/// `cargo build --profile <profile> -p mpm-cli --bin mpm` in `workspace` ([`cargo_profile`]).
pub fn build_solver(workspace: &Path, opt: OptLevel, quiet: bool) -> Result<()> {
    build(workspace, None, opt, &[], quiet)
}

/// [`build_solver`] of the workspace at `workspace` into the target folder `target` (another
/// checkout's build), with `extra` arguments for cargo (e.g. `--no-default-features`).
pub fn build_solver_in(workspace: &Path, target: &Path, opt: OptLevel, extra: &[String], quiet: bool) -> Result<()> {
    build(workspace, Some(target), opt, extra, quiet)
}

fn build(workspace: &Path, target: Option<&Path>, opt: OptLevel, extra: &[String], quiet: bool) -> Result<()> {
    let cargo = std::env::var_os("CARGO").unwrap_or_else(|| "cargo".into());
    let profile = cargo_profile(opt)?;
    if !quiet && target.is_none() {
        eprintln!("building the {opt} solver: cargo build --profile {profile} -p mpm-cli --bin mpm");
    }
    let mut cmd = Command::new(&cargo);
    cmd.current_dir(workspace).args(["build", "--profile", &profile, "-p", "mpm-cli", "--bin", "mpm"]).args(extra);
    if let Some(t) = target {
        cmd.env("CARGO_TARGET_DIR", t);
    }
    if quiet {
        cmd.arg("--quiet");
    }
    let status = cmd
        .status()
        .with_context(|| format!("cannot run cargo ({}) to build the solver", Path::new(&cargo).display()))?;
    if !status.success() {
        bail!("building the `mpm` solver in profile {profile} in {} failed ({status})", workspace.display());
    }
    Ok(())
}
