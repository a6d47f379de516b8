//! `manifest.json`: what machine and software a campaign ran on, once per campaign.
//!
//! The machine part ([`MachineInfo`], with the fingerprint) comes from
//! [`crate::machine::fingerprint`]. The manifest also records the software environment: rustc
//! version, the workspace's Cargo profiles, RUSTFLAGS, the solver binaries' SHA-256, relevant
//! environment variables (`RAYON_*`, `OMP_*`, `MPM_*`, `HWLOC_*`, `MALLOC_*`, `LD_PRELOAD`,
//! ...), the CPU frequency governor where readable, the kernel, and the git commit with a
//! dirty flag.
//!
//! The manifest is append-only: the top-level `machine` and `software` are those of the
//! session that created the campaign and are never rewritten; each invocation of `mpm-bench
//! run` that has runs to do adds a [`Session`] with its own machine, software, binaries, seed,
//! command line and counts (a run with nothing to do writes nothing). The hwloc topology is
//! exported beside it as `topology.xml` once, when the campaign is created.
//!
//! Under a scheduler (`mpm-bench run --scheduler slurm`) the runs run on other machines: the
//! top-level `machine` is then the one that submitted the jobs, and `nodes` holds, by
//! fingerprint, the machine of every node type a run ran on ([`NodeInfo`], as the first job
//! on such a node found it, with its hwloc topology beside it under `nodes/`).
//!
//! `reference: true` marks a committed reference campaign: read-only, never a resume target
//! (`mpm-bench run` starts a new folder instead; see the README's "Results").

use crate::machine::fingerprint::MachineInfo;
use crate::machine::load::Calibration;
use anyhow::{Context, Result};
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::path::Path;
use std::process::Command;

/// Version of the manifest layout.
pub const MANIFEST_VERSION: u32 = 1;

/// A solver binary.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct BinaryInfo {
    /// `o3` / `o0`.
    pub opt_level: String,
    /// Path.
    pub path: String,
    /// SHA-256, hex.
    pub sha256: String,
}

/// Git state of the workspace.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct GitInfo {
    /// Commit hash, or `unknown`.
    pub commit: String,
    /// Uncommitted changes to tracked files.
    pub dirty: bool,
}

/// The software part of the manifest.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SoftwareInfo {
    /// `rustc -vV` first line, or `unknown`.
    pub rustc: String,
    /// `[profile.*]` tables of the workspace Cargo.toml.
    pub cargo_profiles: serde_json::Value,
    /// `RUSTFLAGS` / `CARGO_ENCODED_RUSTFLAGS` (empty when unset).
    pub rustflags: String,
    /// Solver binaries.
    pub binaries: Vec<BinaryInfo>,
    /// Relevant environment variables.
    pub env: BTreeMap<String, String>,
    /// hwloc API version the harness was built against (`2.9.0`).
    pub hwloc_api: String,
    /// Version of this harness.
    pub harness_version: String,
    /// Git state.
    pub git: GitInfo,
    /// Campaigns with several ranks: the launcher's `--version` (first line), e.g.
    /// `mpirun (Open MPI) 4.1.4`; `null` otherwise.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub mpi_launcher: Option<String>,
}

/// What one session of a campaign did (in the manifest and in the closing summary).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct SessionCounts {
    /// Runs in the matrix.
    pub planned: usize,
    /// Runs already in the CSV at the start (resumed past).
    pub already_done: usize,
    /// Rows written by this session.
    pub written: usize,
    /// Rows written with status ok.
    pub ok: usize,
    /// Skipped rows written.
    pub skipped: usize,
    /// Failed rows written.
    pub failed: usize,
    /// Invalid rows written.
    pub invalid: usize,
    /// Oversubscribed rows written.
    pub oversubscribed: usize,
    /// Rows written flagged `host_noisy` (a busy host, or a worker short of CPU time).
    #[serde(default)]
    pub noisy: usize,
    /// Stopped by Ctrl-C / SIGTERM.
    pub interrupted: bool,
    /// Under a scheduler: runs left in its queue (submitted, not yet collected) at the end.
    #[serde(default, skip_serializing_if = "is_zero")]
    pub queued: usize,
}

fn is_zero(n: &usize) -> bool {
    *n == 0
}

/// One invocation of `mpm-bench run` on this campaign.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Session {
    /// Start (RFC 3339 UTC).
    pub started: String,
    /// End (RFC 3339 UTC), empty while running or when killed.
    pub finished: String,
    /// Command line.
    pub command: String,
    /// Seed of the shuffled run order.
    pub seed: u64,
    /// What the session did.
    #[serde(flatten)]
    pub counts: SessionCounts,
    /// Binaries used (hashes may change between sessions after a rebuild).
    pub binaries: Vec<BinaryInfo>,
    /// Git state at the start.
    pub git: GitInfo,
    /// The machine this session ran on (`null` in manifests written before sessions
    /// recorded it).
    #[serde(default)]
    pub machine: Option<MachineInfo>,
    /// The software of this session.
    #[serde(default)]
    pub software: Option<SoftwareInfo>,
    /// The host calibration at the session's start (rows store their ratio to it).
    #[serde(default)]
    pub calibration: Option<Calibration>,
    /// Where the session's runs ran when not here: `slurm cluster <name>, partition ...`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub scheduler: Option<String>,
}

/// The machine of a node a run ran on (under a scheduler): written by the first job on a
/// node of this fingerprint to `nodes/<fingerprint>.json`, copied into the manifest.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct NodeInfo {
    /// The node that wrote it (other nodes of the same fingerprint are the same machine).
    pub node: String,
    /// Its machine: fingerprint, CPU, topology, caches, memory, OS.
    pub machine: MachineInfo,
    /// Its hwloc topology (XML), relative to the campaign folder; empty when not exported.
    pub topology: String,
}

/// `manifest.json`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Manifest {
    /// [`MANIFEST_VERSION`].
    pub manifest_version: u32,
    /// Campaign id.
    pub campaign_id: String,
    /// The resolved campaign (matrix, budgets, overrides).
    pub campaign: serde_json::Value,
    /// A committed reference campaign: read-only, refused as a resume target.
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub reference: bool,
    /// Machine of the session that created the campaign.
    pub machine: MachineInfo,
    /// Software environment of the session that created the campaign.
    pub software: SoftwareInfo,
    /// Every session that ran on this campaign, each with its own machine and software.
    pub sessions: Vec<Session>,
    /// The machines of the nodes the runs ran on under a scheduler, by fingerprint (empty
    /// for a campaign run here: its machine is `machine`).
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub nodes: BTreeMap<String, NodeInfo>,
}

impl Manifest {
    /// The machine of fingerprint `fp`: a node's, or the campaign's own.
    pub fn machine_of(&self, fp: &str) -> Option<&MachineInfo> {
        self.nodes.get(fp).map(|n| &n.machine).or_else(|| (self.machine.fingerprint == fp).then_some(&self.machine))
    }
}

/// Software part of the manifest.
pub fn software_info(workspace: Option<&Path>, binaries: Vec<BinaryInfo>) -> SoftwareInfo {
    let rustc = Command::new(std::env::var("RUSTC").unwrap_or_else(|_| "rustc".into()))
        .arg("-vV")
        .output()
        .ok()
        .filter(|o| o.status.success())
        .map(|o| {
            let t = String::from_utf8_lossy(&o.stdout).to_string();
            let first = t.lines().next().unwrap_or("").to_string();
            let host = t.lines().find_map(|l| l.strip_prefix("host: ")).unwrap_or("");
            if host.is_empty() {
                first
            } else {
                format!("{first} (host {host})")
            }
        })
        .unwrap_or_else(|| "unknown".into());
    let cargo_profiles = workspace
        .and_then(|w| std::fs::read_to_string(w.join("Cargo.toml")).ok())
        .and_then(|t| t.parse::<toml::Table>().ok())
        .and_then(|t| t.get("profile").cloned())
        .and_then(|p| serde_json::to_value(p).ok())
        .unwrap_or(serde_json::Value::Null);
    let rustflags = std::env::var("RUSTFLAGS")
        .or_else(|_| std::env::var("CARGO_ENCODED_RUSTFLAGS").map(|s| s.replace('\x1f', " ")))
        .unwrap_or_default();
    let api = hwlocality::hwloc_api_version();
    SoftwareInfo {
        rustc,
        cargo_profiles,
        rustflags,
        binaries,
        env: relevant_env(),
        hwloc_api: format!("{}.{}.{}", api >> 16, (api >> 8) & 0xff, api & 0xff),
        harness_version: env!("CARGO_PKG_VERSION").into(),
        git: git_info(workspace),
        mpi_launcher: None,
    }
}

/// Environment variables that can change a measurement.
pub fn relevant_env() -> BTreeMap<String, String> {
    const PREFIXES: [&str; 15] = [
        "RAYON_",
        "OMP_",
        "GOMP_",
        "KMP_",
        "MPM_",
        "HWLOC_",
        "MALLOC_",
        "CARGO_PROFILE_",
        "CARGO_BUILD_",
        "RUST_MIN_STACK",
        // MPI runtimes: tuning parameters and the transport change the exchange's time.
        "OMPI_",
        "PMIX_MCA_",
        "MPICH_",
        "I_MPI_",
        "UCX_",
    ];
    const EXACT: [&str; 5] =
        ["RUSTFLAGS", "CARGO_ENCODED_RUSTFLAGS", "CARGO_TARGET_DIR", "LD_PRELOAD", "LD_LIBRARY_PATH"];
    std::env::vars().filter(|(k, _)| PREFIXES.iter().any(|p| k.starts_with(p)) || EXACT.contains(&k.as_str())).collect()
}

/// Git commit and dirty flag of `workspace` (or the current directory).
pub fn git_info(workspace: Option<&Path>) -> GitInfo {
    let dir = workspace.map(Path::to_path_buf).unwrap_or_else(|| ".".into());
    let run = |args: &[&str]| -> Option<String> {
        Command::new("git")
            .arg("-C")
            .arg(&dir)
            .args(args)
            .output()
            .ok()
            .filter(|o| o.status.success())
            .map(|o| String::from_utf8_lossy(&o.stdout).trim().to_string())
    };
    match run(&["rev-parse", "HEAD"]) {
        Some(commit) => GitInfo {
            commit,
            dirty: run(&["status", "--porcelain", "--untracked-files=no"]).is_some_and(|s| !s.is_empty()),
        },
        None => GitInfo { commit: "unknown".into(), dirty: false },
    }
}

/// Read a manifest.
pub fn read(path: &Path) -> Result<Manifest> {
    let text = std::fs::read_to_string(path).with_context(|| format!("cannot read {}", path.display()))?;
    serde_json::from_str(&text).with_context(|| format!("bad manifest {}", path.display()))
}

/// Write a manifest (atomically).
pub fn write(path: &Path, m: &Manifest) -> Result<()> {
    Ok(mpm_host::atomic::write_atomic(path, serde_json::to_string_pretty(m)?.as_bytes())?)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn software_info_has_profiles() {
        let ws = Path::new(env!("CARGO_MANIFEST_DIR")).parent().unwrap();
        let s = software_info(Some(ws), vec![]);
        assert!(s.cargo_profiles.get("o0").is_some(), "{:?}", s.cargo_profiles);
        assert!(s.hwloc_api.starts_with("2."));
    }
}
