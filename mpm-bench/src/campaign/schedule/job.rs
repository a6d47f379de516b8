//! One run as a batch job: the file the harness writes for it ([`JobFile`],
//! `json/<run id>.job.json`) and what `mpm-bench job FILE` does with it on the node the
//! scheduler chose ([`run`]).
//!
//! The job runs the run exactly as a local campaign runs it, with the same code
//! ([`RunContext::run_one`]) and this node as the machine: the pinning policy places the
//! workers on this node's topology, the memory guard weighs this node's memory, the host
//! watch probes this node (a job is a session of one run: its calibration ratios are 1), the
//! solver runs as `mpm run --spec FILE` and its summary is checked against the request (a
//! worker seen on another CPU than placed makes the row invalid). The job writes
//!
//! * `json/<run id>.node.json` when it starts ([`Started`]: the node and its fingerprint),
//!   so that even a job the scheduler kills later names the machine it ran on;
//! * `nodes/<fingerprint>.json` and `nodes/<fingerprint>.topology.xml` the first time a node
//!   of that machine runs a job (the manifest's `nodes`, see [`NodeInfo`]);
//! * `json/<run id>.row.json`, the finished row with the job start that wrote it
//!   ([`RowFile`]), which the harness appends to `runs.csv`;
//! * or, when the solver stopped at a complete checkpoint ([`LAST_CHECKPOINT_EXIT`]: Slurm's
//!   SIGUSR1 before the time limit, or its SIGTERM), `json/<run id>.stopped.json`
//!   ([`Stopped`]) and no row: the run is still to do, and the next job of it continues from
//!   that checkpoint.
//!
//! A checkpointed run's job forwards SIGUSR1 and SIGTERM to the solver as SIGUSR1 (for a run
//! over several ranks, to the launcher, which passes it to every rank): the solver writes a
//! last checkpoint after its current step and exits ([`forward_stop_signals`]).
//!
//! Inside a Slurm job, nothing is written unless the campaign's ledger (`slurm-jobs.json`)
//! names this job and this start of it as its run's ([`Fence`]): a job started again by
//! Slurm, or one whose run was collected or given up meanwhile, exits with [`FENCED`]
//! without touching the run's files. The check is made when the job starts and again just
//! before it writes the row.
//!
//! Before running, the job checks that the solver binary on this node is the one the
//! campaign hashed (the binaries must be the same on every node); if not, it fails with
//! exit code 2 and says so in the job's output.

pub use super::ledger::{read_json, write_json};
use super::ledger::{Fence, RowFile, FENCED};
use crate::campaign::exec::process::ProcessRunner;
use crate::campaign::exec::run::RunContext;
use crate::campaign::exec::solver::{sha256_file, Solver};
use crate::campaign::exec::watch::{HostWatch, WatchSettings};
use crate::campaign::plan::matrix::{Campaign, PlannedRun};
use crate::campaign::schedule::install_interrupt_handler;
use crate::campaign::store::manifest::{GitInfo, NodeInfo};
use crate::machine::fingerprint;
use crate::machine::topology::Machine;
use anyhow::{bail, Context, Result};
use mpm_host::atomic::write_atomic;
use nix::sys::signal::{kill, SigSet, Signal};
use nix::unistd::Pid;
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};
use std::time::Duration;

/// Everything a job needs to run one run of a campaign on a node.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct JobFile {
    /// The campaign (its id, seed, launcher and memory limit).
    pub campaign: Campaign,
    /// The campaign's per-run time limit (not part of the campaign's serialised form).
    pub timeout: Option<Duration>,
    /// The git state of the session that submitted the job.
    pub git: GitInfo,
    /// The solver binary (its path on every node, and its hash).
    pub solver: Solver,
    /// The run.
    pub run: PlannedRun,
    /// Its position in the session's seeded order.
    pub order_index: usize,
    /// Its run id (the name of its files).
    pub run_id: String,
    /// Watch the node around the run (`None`: the `host_*` columns stay empty).
    pub watch: Option<WatchSettings>,
}

/// What a job writes when it starts: where it runs.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Started {
    /// The node (Slurm node name, else host name).
    pub node: String,
    /// Its machine fingerprint.
    pub fingerprint: String,
}

/// The exit status of `mpm` (and of the job) stopped after writing its last checkpoint:
/// `EX_TEMPFAIL` of `sysexits.h`, "try again later" (`mpm resume` continues the run).
pub const LAST_CHECKPOINT_EXIT: i32 = 75;

/// `json/<run id>.stopped.json`: the run's solver stopped at a complete checkpoint.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Stopped {
    /// The job start whose solver stopped.
    pub fence: Fence,
    /// What the solver said.
    pub reason: String,
}

/// `json/<run id>.stopped.json`.
pub fn stopped_path(json_dir: &Path, run_id: &str) -> PathBuf {
    json_dir.join(format!("{run_id}.stopped.json"))
}

/// The note of a job whose solver stopped at a complete checkpoint, if it left one.
pub fn read_stopped(json_dir: &Path, run_id: &str) -> Result<Option<Stopped>> {
    read_if_there(&stopped_path(json_dir, run_id))
}

/// The JSON file `p` as a `T`, `None` when there is none.
fn read_if_there<T: for<'de> Deserialize<'de>>(p: &Path) -> Result<Option<T>> {
    if !p.is_file() {
        return Ok(None);
    }
    read_json(p).map(Some)
}

/// Take SIGUSR1 and SIGTERM in a thread of their own (blocked in this thread, and so in the
/// threads started after it: call it first; child processes start with no signal blocked)
/// and pass each on to this process's children, the solver or its launcher, as SIGUSR1: a
/// run with a checkpoint folder then writes a last checkpoint and exits with
/// [`LAST_CHECKPOINT_EXIT`] (Open MPI's `mpirun` passes SIGUSR1 to its ranks, while it ends
/// them at once on SIGTERM).
pub fn forward_stop_signals() {
    let mut set = SigSet::empty();
    set.add(Signal::SIGUSR1);
    set.add(Signal::SIGTERM);
    if let Err(e) = set.thread_block() {
        eprintln!("warning: cannot take SIGUSR1 and SIGTERM for the solver's last checkpoint: {e}");
        return;
    }
    let spawned = std::thread::Builder::new().name("mpm-bench-signals".into()).spawn(move || {
        while let Ok(signal) = set.wait() {
            let pids = children();
            eprintln!("mpm-bench job: {signal}: SIGUSR1 to the solver (pids {pids:?}) for its last checkpoint");
            for pid in pids {
                let _ = kill(Pid::from_raw(pid), Signal::SIGUSR1);
            }
        }
    });
    if let Err(e) = spawned {
        eprintln!("warning: cannot take SIGUSR1 and SIGTERM for the solver's last checkpoint: {e}");
    }
}

/// This process's child processes (`/proc/self/task/*/children`).
fn children() -> Vec<i32> {
    let Ok(tasks) = std::fs::read_dir("/proc/self/task") else { return Vec::new() };
    tasks
        .flatten()
        .filter_map(|t| std::fs::read_to_string(t.path().join("children")).ok())
        .flat_map(|text| text.split_whitespace().filter_map(|p| p.parse().ok()).collect::<Vec<i32>>())
        .collect()
}

/// `json/<run id>.job.json`.
pub fn job_path(json_dir: &Path, run_id: &str) -> PathBuf {
    json_dir.join(format!("{run_id}.job.json"))
}

/// `json/<run id>.row.json`: the finished row.
pub fn row_path(json_dir: &Path, run_id: &str) -> PathBuf {
    json_dir.join(format!("{run_id}.row.json"))
}

/// `json/<run id>.node.json`: where the job started.
pub fn started_path(json_dir: &Path, run_id: &str) -> PathBuf {
    json_dir.join(format!("{run_id}.node.json"))
}

/// The finished row a job wrote (with the start that wrote it), if it has.
pub fn read_row(json_dir: &Path, run_id: &str) -> Result<Option<RowFile>> {
    read_if_there(&row_path(json_dir, run_id))
}

/// Where the job of `run_id` started, if it has.
pub fn read_started(json_dir: &Path, run_id: &str) -> Option<Started> {
    read_json(&started_path(json_dir, run_id)).ok()
}

/// The machine of fingerprint `fp` as a node wrote it under the campaign folder `dir`.
pub fn read_node(dir: &Path, fp: &str) -> Result<Option<NodeInfo>> {
    read_if_there(&dir.join("nodes").join(format!("{fp}.json")))
}

/// Record this node's machine under the campaign folder `dir` (`nodes/<fp>.json` and its
/// topology), unless a node of the same machine did already.
fn record_node(dir: &Path, machine: &Machine, node: &str) -> Result<String> {
    let info = fingerprint::machine_info(machine);
    let fp = info.fingerprint.clone();
    let nodes = dir.join("nodes");
    let json = nodes.join(format!("{fp}.json"));
    if !json.is_file() {
        std::fs::create_dir_all(&nodes).with_context(|| format!("cannot create {}", nodes.display()))?;
        let topology = match crate::machine::topology::export_xml() {
            Ok(xml) => {
                let name = format!("{fp}.topology.xml");
                write_atomic(&nodes.join(&name), xml.as_bytes())?;
                format!("nodes/{name}")
            }
            Err(e) => {
                eprintln!("warning: no topology of node {node}: {e:#}");
                String::new()
            }
        };
        write_json(&json, &NodeInfo { node: node.to_string(), machine: info, topology })?;
    }
    Ok(fp)
}

/// Whether this start of the Slurm job may write the files of run `run_id` of campaign
/// folder `dir` (always, outside Slurm); when not, says why on standard error.
fn fenced_out(fence: Option<&Fence>, dir: &Path, run_id: &str) -> bool {
    let Some(f) = fence else { return false };
    match f.check(dir, run_id) {
        Ok(()) => false,
        Err(why) => {
            eprintln!("mpm-bench job: not running run {run_id}, writing nothing: {why}");
            true
        }
    }
}

/// `mpm-bench job FILE`: run the job's run on this node and write its row; the exit code is
/// 0 when a row was written, [`LAST_CHECKPOINT_EXIT`] when the solver stopped at a complete
/// checkpoint (no row: the run is still to do), 130 when the job was stopped (cancelled, out
/// of time) before the run ended, [`FENCED`] when the ledger does not name this job start as
/// its run's.
pub fn run(file: &Path) -> Result<i32> {
    let job: JobFile = read_json(file)?;
    let json_dir = file.parent().unwrap_or(Path::new(".")).to_path_buf();
    let dir = json_dir.parent().unwrap_or(Path::new(".")).to_path_buf();
    let fence = Fence::here();
    if fence.is_some() && job.campaign.checkpoint_every.is_some() {
        forward_stop_signals();
    }
    if fenced_out(fence.as_ref(), &dir, &job.run_id) {
        return Ok(FENCED);
    }
    let machine = Machine::detect()?;
    let node = crate::util::node_name();
    let fp = record_node(&dir, &machine, &node)?;
    write_json(&started_path(&json_dir, &job.run_id), &Started { node: node.clone(), fingerprint: fp })?;
    let here = sha256_file(&job.solver.path)?;
    if here != job.solver.sha256 {
        bail!(
            "the {} solver binary {} on node {node} is not the one the campaign was submitted with (sha256 {}, \
             submitted {}): every node must see the same binaries (a shared filesystem)",
            job.solver.opt,
            job.solver.path.display(),
            &here[..16],
            &job.solver.sha256[..job.solver.sha256.len().min(16)]
        );
    }
    let interrupted = install_interrupt_handler();
    let mut campaign = job.campaign;
    campaign.timeout = job.timeout;
    let ctx = RunContext {
        campaign: &campaign,
        machine: &machine,
        git: job.git,
        json_dir: json_dir.clone(),
        // The campaign folder is shared with the submitting host: a job's checkpoints are
        // where a later job of the same run (after a time limit or a cancel) continues.
        checkpoint_root: dir.join("checkpoints"),
        interrupted: &interrupted,
    };
    // A job is a session of one run: a short start probe, then the probes around the run.
    let mut watch =
        job.watch.map(|w| HostWatch::start(WatchSettings { start_window: w.window, ..w }, machine.usable_pus().len()));
    let mut runner = ProcessRunner::new(interrupted.clone());
    match ctx.run_one(&mut runner, watch.as_mut(), &job.solver, &job.run, job.order_index, job.run_id.clone())? {
        Some(_) if fenced_out(fence.as_ref(), &dir, &job.run_id) => Ok(FENCED),
        Some(row) if row.outcome.exit_code == Some(LAST_CHECKPOINT_EXIT) && campaign.checkpoint_every.is_some() => {
            let stopped = Stopped { fence: fence.unwrap_or_default(), reason: row.outcome.reason };
            write_json(&stopped_path(&json_dir, &job.run_id), &stopped)?;
            eprintln!("{}: stopped at a complete checkpoint on {node}; no row", job.run.describe());
            Ok(LAST_CHECKPOINT_EXIT)
        }
        Some(row) => {
            let status = row.outcome.status.as_str();
            write_json(&row_path(&json_dir, &job.run_id), &RowFile { fence: fence.unwrap_or_default(), row })?;
            eprintln!("{}: {status} on {node}", job.run.describe());
            Ok(0)
        }
        None => {
            eprintln!("{}: stopped before it ended; no row", job.run.describe());
            Ok(130)
        }
    }
}
