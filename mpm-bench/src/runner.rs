//! Running a campaign: the solver binaries, the memory guard, one fresh child process per
//! run, and the loop that writes a CSV row after every run.
//!
//! * Binaries: `mpm` is built in the Cargo profiles `o3` and `o0`
//!   (`cargo build --profile o3 -p mpm-cli --bin mpm`) or located in `target/<profile>/`;
//!   `MPM_BENCH_SOLVER_O3` / `MPM_BENCH_SOLVER_O0` point at other binaries. Each binary's
//!   SHA-256 goes into the manifest and (abbreviated) into every row.
//! * [`Runner`]: [`ProcessRunner`] spawns `mpm run ... --json FILE --quiet` as a fresh
//!   process (clean memory figure, no state carried over); [`MockRunner`] fakes it in
//!   microseconds for tests.
//! * Memory guard ([`estimate_memory`]): before each run its memory is estimated (AE grows
//!   with threads); a run that does not fit in 90 % of the memory available now (or of
//!   `--mem-limit`) is recorded as `skipped` with the reason, not attempted.
//! * Oversubscription: rows with more threads than usable PUs are flagged and the terminal
//!   says so once per campaign. A run whose observed CPUs differ from the requested ones is
//!   recorded `invalid`.
//! * Ctrl-C / SIGTERM ([`install_interrupt_handler`]): the run in progress is stopped and not
//!   recorded; every finished run is already in the CSV, so the campaign resumes later.

use crate::manifest::{self, BinaryInfo, Manifest, Session};
use crate::matrix::{Campaign, OptLevel, RunSpec, Strategy};
use crate::record::{cpus_cell, read_rows, CsvLog, Row, RunKey, Status, SCHEMA_VERSION};
use crate::topology::{format_cpu_list, human_bytes, Machine, PinPolicy};
use anyhow::{anyhow, bail, Context, Result};
use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};
use serde_json::Value;
use sha2::{Digest, Sha256};
use std::collections::{HashMap, HashSet};
use std::io::Read;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::{Arc, OnceLock};
use std::time::{Duration, Instant};

// ------------------------------------------------------------------------------------------
// Models and the memory guard
// ------------------------------------------------------------------------------------------

/// Particle and node counts of a Taylor bar model (the paper's Table 2 sizes).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ModelSize {
    /// Particles.
    pub particles: u64,
    /// Grid nodes.
    pub nodes: u64,
}

/// Size of Model `m` (1-4).
pub fn model_size(m: u32) -> Option<ModelSize> {
    match m {
        1 => Some(ModelSize { particles: 56_056, nodes: 53_361 }),
        2 => Some(ModelSize { particles: 244_341, nodes: 175_273 }),
        3 => Some(ModelSize { particles: 1_155_192, nodes: 1_053_493 }),
        4 => Some(ModelSize { particles: 12_416_320, nodes: 8_302_185 }),
        _ => None,
    }
}

/// The impact scenario's models: `(particle spacing, cell size)` in metres. 1-3 are the
/// paper's small model (0.53 mm spacing, 848,104 particles) with its three cell sizes
/// 2.12 / 1.59 / 1.06 mm; 4 is the large model (0.21 mm, 13.5 M particles, 1.0 mm cells).
pub fn impact_variant(m: u32) -> Option<(f64, f64)> {
    match m {
        1 => Some((0.53e-3, 2.12e-3)),
        2 => Some((0.53e-3, 1.59e-3)),
        3 => Some((0.53e-3, 1.06e-3)),
        4 => Some((0.21e-3, 1.0e-3)),
        _ => None,
    }
}

/// Size of `model` of `scenario`. For the impact the node count is that of the adaptive grid
/// around the debris cloud at 30.6 µs (about 160 x 160 x 220 mm), an upper estimate.
pub fn scenario_size(scenario: &str, m: u32) -> Option<ModelSize> {
    if scenario != "impact" {
        return model_size(m);
    }
    let (spacing, cell) = impact_variant(m)?;
    let particles = if spacing < 0.3e-3 { 13_537_926 } else { 848_104 };
    let n = |len: f64| (len / cell).ceil() as u64 + 1;
    Some(ModelSize { particles, nodes: n(0.16) * n(0.16) * n(0.22) })
}

// The constants below were fitted to the solver's own `model_memory_bytes` on Models 1-3
// (serial: 137 B per particle + 128 B per node reproduces all three exactly) and checked
// against the peak RSS of Model 4 (AE, 1 and 8 threads: 3.4 and 8.1 GB, within 1 %). AE keeps
// one private 80-byte copy of the nodal arrays per worker, so it grows with every thread;
// DD adds binning and sub-grid arrays that barely depend on the thread count.

/// Bytes per particle (state, stress, strain, material history).
pub const BYTES_PER_PARTICLE: u64 = 137;
/// Bytes per grid node (mass, momentum, force, velocity, flags).
pub const BYTES_PER_NODE: u64 = 128;
/// Extra bytes per node for each AE worker (its private copy of the scattered arrays).
pub const AE_BYTES_PER_NODE_PER_THREAD: u64 = 80;
/// DD binning overhead per particle (patch index, permutation).
pub const DD_BYTES_PER_PARTICLE: u64 = 8;
/// DD sub-grid overhead per node (patch-local arrays and halo bookkeeping).
pub const DD_BYTES_PER_NODE: u64 = 80;
/// Process baseline (binary, runtime, allocator), plus [`BYTES_PER_THREAD`] per worker.
pub const BASE_BYTES: u64 = 16 << 20;
/// Per-worker slack (stack pages touched, DD halo growth with the patch count).
pub const BYTES_PER_THREAD: u64 = 2 << 20;

/// Estimated peak memory of a run of `model` of `scenario`, bytes.
pub fn estimate_memory(scenario: &str, model: u32, strategy: Strategy, threads: usize) -> u64 {
    let t = threads.max(1) as u64;
    let base = BASE_BYTES + t * BYTES_PER_THREAD;
    let Some(s) = scenario_size(scenario, model) else { return base };
    let mut b = base + s.particles * BYTES_PER_PARTICLE + s.nodes * BYTES_PER_NODE;
    match strategy {
        Strategy::Serial => {}
        Strategy::Ae => b += t * AE_BYTES_PER_NODE_PER_THREAD * s.nodes,
        Strategy::Dd => b += s.particles * DD_BYTES_PER_PARTICLE + s.nodes * DD_BYTES_PER_NODE,
    }
    b
}

/// Memory available to a new process now, bytes: `MemAvailable`, capped by a cgroup v2
/// `memory.max` when one is set.
pub fn available_memory() -> Option<u64> {
    let meminfo = std::fs::read_to_string("/proc/meminfo").ok()?;
    let avail = meminfo
        .lines()
        .find(|l| l.starts_with("MemAvailable:"))
        .and_then(|l| l.split_whitespace().nth(1))
        .and_then(|v| v.parse::<u64>().ok())?
        * 1024;
    let cg = std::fs::read_to_string("/sys/fs/cgroup/memory.max").ok().and_then(|s| s.trim().parse::<u64>().ok());
    let used = std::fs::read_to_string("/sys/fs/cgroup/memory.current")
        .ok()
        .and_then(|s| s.trim().parse::<u64>().ok())
        .unwrap_or(0);
    Some(match cg {
        Some(max) => avail.min(max.saturating_sub(used)),
        None => avail,
    })
}

/// Fraction of the available memory a run may use.
pub const MEMORY_HEADROOM: f64 = 0.9;

/// Why a run does not fit, or `None` when it does.
pub fn memory_verdict(estimate: u64, available: Option<u64>, limit: Option<u64>) -> Option<String> {
    let (cap, source) = match (available, limit) {
        (Some(a), Some(l)) if l < a => (l, "the --mem-limit"),
        (None, Some(l)) => (l, "the --mem-limit"),
        (Some(a), _) => (a, "memory available now"),
        (None, None) => return None,
    };
    let allowed = (cap as f64 * MEMORY_HEADROOM) as u64;
    (estimate > allowed).then(|| {
        format!(
            "memory guard: estimated {} exceeds {:.0}% of {} ({})",
            human_bytes(estimate),
            MEMORY_HEADROOM * 100.0,
            source,
            human_bytes(cap)
        )
    })
}

// ------------------------------------------------------------------------------------------
// Solver binaries
// ------------------------------------------------------------------------------------------

/// A solver binary of one optimisation level.
#[derive(Clone, Debug, PartialEq)]
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
    let mut f = std::fs::File::open(path).with_context(|| format!("cannot open {}", path.display()))?;
    let mut h = Sha256::new();
    let mut buf = vec![0u8; 1 << 16];
    loop {
        let n = f.read(&mut buf)?;
        if n == 0 {
            break;
        }
        h.update(&buf[..n]);
    }
    Ok(manifest::hex(&h.finalize()))
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
            let path = target_dir(ws).join(opt.as_str()).join("mpm");
            if build {
                build_solver(ws, opt, quiet)?;
            }
            path
        };
        if !path.is_file() {
            bail!(
                "solver binary {} not found (build it with `cargo build --profile {} -p mpm-cli --bin mpm`)",
                path.display(),
                opt
            );
        }
        let sha256 = sha256_file(&path)?;
        out.push(Solver { opt, path, sha256 });
    }
    Ok(out)
}

/// `cargo build --profile <opt> -p mpm-cli --bin mpm` in `workspace`.
pub fn build_solver(workspace: &Path, opt: OptLevel, quiet: bool) -> Result<()> {
    let cargo = std::env::var_os("CARGO").unwrap_or_else(|| "cargo".into());
    if !quiet {
        eprintln!("building the solver: cargo build --profile {opt} -p mpm-cli --bin mpm");
    }
    let mut cmd = Command::new(&cargo);
    cmd.current_dir(workspace).args(["build", "--profile", opt.as_str(), "-p", "mpm-cli", "--bin", "mpm"]);
    if quiet {
        cmd.arg("--quiet");
    }
    let status = cmd
        .status()
        .with_context(|| format!("cannot run cargo ({}) to build the solver", Path::new(&cargo).display()))?;
    if !status.success() {
        bail!("building the `mpm` solver in profile {opt} failed ({status})");
    }
    Ok(())
}

// ------------------------------------------------------------------------------------------
// Runners
// ------------------------------------------------------------------------------------------

/// Everything one run needs.
#[derive(Clone, Debug)]
pub struct RunRequest {
    /// The run.
    pub spec: RunSpec,
    /// Scenario name (`taylor`).
    pub scenario: String,
    /// Solver binary.
    pub binary: PathBuf,
    /// CPU of each worker; `None` = not pinned.
    pub cpus: Option<Vec<usize>>,
    /// Where the solver writes its JSON summary.
    pub json_path: PathBuf,
    /// Per-run time limit.
    pub timeout: Option<Duration>,
}

impl RunRequest {
    /// Arguments of `mpm` for this run.
    pub fn args(&self) -> Vec<String> {
        let s = &self.spec;
        let mut a: Vec<String> = vec!["run".into(), self.scenario.clone()];
        match impact_variant(s.model).filter(|_| self.scenario == "impact") {
            Some((spacing, cell)) => {
                a.extend(["--spacing".into(), format!("{spacing:e}"), "--cell".into(), format!("{cell:e}")])
            }
            None => a.extend(["--model".into(), s.model.to_string()]),
        }
        a.extend(["--strategy".into(), s.strategy.to_string(), "--threads".into(), s.threads.to_string()]);
        if let Some(c) = &self.cpus {
            a.push("--cpus".into());
            a.push(c.iter().map(|x| x.to_string()).collect::<Vec<_>>().join(","));
        }
        if let Some(n) = s.budget.step_limit {
            a.push("--steps".into());
            a.push(n.to_string());
        }
        if let Some(t) = s.budget.end_time {
            a.push("--end-time".into());
            a.push(format!("{t:e}"));
        }
        a.extend(["--grid".into(), s.grid.clone(), "--warmup".into(), s.budget.warmup.to_string()]);
        a.extend(["--json".into(), self.json_path.display().to_string(), "--quiet".into()]);
        a
    }
}

/// How a child process ended.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct RunOutput {
    /// Exit code (`None` when killed by a signal or never started).
    pub exit_code: Option<i32>,
    /// Why it did not run or was stopped (spawn error, timeout, signal).
    pub error: Option<String>,
    /// Last lines of its standard error.
    pub stderr_tail: String,
    /// Wall time of the process (s).
    pub process_wall_s: f64,
    /// Stopped because the campaign was interrupted.
    pub interrupted: bool,
}

/// Runs one configuration.
pub trait Runner {
    /// Run `req`; the summary, if any, is at `req.json_path` afterwards.
    fn run(&mut self, req: &RunRequest) -> RunOutput;
}

/// Spawns the real solver, one fresh process per run.
pub struct ProcessRunner {
    interrupted: Arc<AtomicBool>,
}

impl ProcessRunner {
    /// A runner that stops its child when `interrupted` becomes true.
    pub fn new(interrupted: Arc<AtomicBool>) -> Self {
        Self { interrupted }
    }
}

impl Runner for ProcessRunner {
    fn run(&mut self, req: &RunRequest) -> RunOutput {
        let start = Instant::now();
        let _ = std::fs::remove_file(&req.json_path);
        let mut cmd = Command::new(&req.binary);
        cmd.args(req.args()).stdin(Stdio::null()).stdout(Stdio::null()).stderr(Stdio::piped());
        // Rayon and OpenMP variables must not change the thread count behind our back.
        cmd.env_remove("RAYON_NUM_THREADS");
        let mut child = match cmd.spawn() {
            Ok(c) => c,
            Err(e) => {
                return RunOutput {
                    error: Some(format!("cannot start {}: {e}", req.binary.display())),
                    ..RunOutput::default()
                }
            }
        };
        let mut stderr = child.stderr.take();
        let reader = std::thread::spawn(move || {
            let mut s = String::new();
            if let Some(e) = stderr.as_mut() {
                let _ = e.read_to_string(&mut s);
            }
            s
        });
        let mut out = RunOutput::default();
        loop {
            match child.try_wait() {
                Ok(Some(status)) => {
                    out.exit_code = status.code();
                    if status.code().is_none() {
                        use std::os::unix::process::ExitStatusExt;
                        out.error = Some(format!("killed by signal {}", status.signal().unwrap_or(0)));
                    }
                    break;
                }
                Ok(None) => {}
                Err(e) => {
                    out.error = Some(format!("cannot wait for the solver: {e}"));
                    let _ = child.kill();
                    let _ = child.wait();
                    break;
                }
            }
            if self.interrupted.load(Ordering::SeqCst) {
                let _ = child.kill();
                let _ = child.wait();
                out.interrupted = true;
                out.error = Some("interrupted".into());
                break;
            }
            if req.timeout.is_some_and(|t| start.elapsed() > t) {
                let _ = child.kill();
                let _ = child.wait();
                out.error = Some(format!(
                    "timed out after {}",
                    humantime::format_duration(Duration::from_secs(start.elapsed().as_secs()))
                ));
                break;
            }
            std::thread::sleep(Duration::from_millis(20));
        }
        out.process_wall_s = start.elapsed().as_secs_f64();
        let text = reader.join().unwrap_or_default();
        out.stderr_tail = tail(&text, 3);
        out
    }
}

fn tail(s: &str, lines: usize) -> String {
    let v: Vec<&str> = s.lines().filter(|l| !l.trim().is_empty()).collect();
    v[v.len().saturating_sub(lines)..].join(" | ")
}

/// A fake solver for tests: writes a plausible JSON summary instantly.
#[derive(Clone, Debug, Default)]
pub struct MockRunner {
    /// Every request received, in order.
    pub calls: Vec<RunRequest>,
    /// Fail runs whose description contains this text.
    pub fail_when: Option<String>,
    /// Report CPUs other than the requested ones for runs whose description contains this.
    pub wrong_cpus_when: Option<String>,
    /// Raise the interrupt flag after this many calls (simulated Ctrl-C).
    pub interrupt_after: Option<(usize, Arc<AtomicBool>)>,
    /// Sleep this long per run.
    pub delay: Duration,
}

impl Runner for MockRunner {
    fn run(&mut self, req: &RunRequest) -> RunOutput {
        self.calls.push(req.clone());
        std::thread::sleep(self.delay);
        if let Some((n, flag)) = &self.interrupt_after {
            if self.calls.len() > *n {
                flag.store(true, Ordering::SeqCst);
                return RunOutput { interrupted: true, error: Some("interrupted".into()), ..RunOutput::default() };
            }
        }
        let desc = req.spec.describe();
        if self.fail_when.as_ref().is_some_and(|f| desc.contains(f.as_str())) {
            return RunOutput {
                exit_code: Some(1),
                stderr_tail: "mock failure".into(),
                process_wall_s: 0.01,
                ..RunOutput::default()
            };
        }
        let s = &req.spec;
        let size = scenario_size(&s.scenario, s.model).unwrap_or(ModelSize { particles: 1000, nodes: 1000 });
        let steps = s.budget.step_limit.unwrap_or(100);
        let speed = match s.strategy {
            Strategy::Dd => 0.9,
            _ => 0.8,
        } * (s.threads.min(2) as f64);
        let per_step = size.particles as f64 * 50e-9 * if s.opt == OptLevel::O0 { 8.0 } else { 1.0 } / speed;
        let wall = per_step * steps as f64;
        let requested = req.cpus.clone().unwrap_or_default();
        let observed: Vec<usize> = if self.wrong_cpus_when.as_ref().is_some_and(|f| desc.contains(f.as_str())) {
            requested.iter().map(|c| c + 1).collect()
        } else {
            requested.clone()
        };
        let mut substages = serde_json::Map::new();
        for (k, f) in
            [("scatter", 0.3), ("assembly", 0.1), ("grid_update", 0.05), ("gather", 0.2), ("stress_update", 0.35)]
        {
            substages.insert(k.into(), Value::from(wall * f));
        }
        let summary = serde_json::json!({
            "scenario": req.scenario, "model": s.model, "strategy": s.strategy.as_str(),
            "threads": s.threads, "opt_level": s.opt.as_str(), "grid_mode": s.grid, "eos": "mie-gruneisen",
            "particles": size.particles, "cells": size.nodes / 2, "nodes": size.nodes, "mean_nodes": size.nodes as f64,
            "steps": steps, "dt_first": 1e-8, "sim_time": steps as f64 * 1e-8, "end_reason": "step_limit",
            "wall_s": wall, "grid_stage_s": wall * 0.45, "particle_stage_s": wall * 0.55, "substages": substages,
            "ns_per_particle_step": per_step * 1e9 / size.particles as f64,
            "particle_steps_per_s": size.particles as f64 / per_step, "steady_s_per_step": per_step,
            "peak_rss_bytes": estimate_memory(&s.scenario, s.model, s.strategy, s.threads),
            "requested_cpus": requested, "observed_cpus": observed,
            "kinetic_energy_initial": 1000.0, "kinetic_energy": 900.0, "internal_energy": 99.0,
            "initial_length_m": 0.0254, "final_length_m": 0.0253, "face_diameter_m": 0.0077, "failed_particles": 0,
            "warmup_steps": s.budget.warmup, "oversubscribed": false
        });
        if let Err(e) = std::fs::write(&req.json_path, summary.to_string()) {
            return RunOutput { error: Some(format!("mock cannot write JSON: {e}")), ..RunOutput::default() };
        }
        RunOutput { exit_code: Some(0), process_wall_s: wall + 0.05, ..RunOutput::default() }
    }
}

// ------------------------------------------------------------------------------------------
// Interrupts
// ------------------------------------------------------------------------------------------

static INTERRUPTED: OnceLock<Arc<AtomicBool>> = OnceLock::new();

/// Install (once per process) a Ctrl-C / SIGTERM handler that raises the returned flag; a
/// second Ctrl-C exits at once (every finished row is already on disk).
pub fn install_interrupt_handler() -> Arc<AtomicBool> {
    INTERRUPTED
        .get_or_init(|| {
            let flag = Arc::new(AtomicBool::new(false));
            let count = Arc::new(AtomicUsize::new(0));
            let f = flag.clone();
            let result = ctrlc::set_handler(move || {
                f.store(true, Ordering::SeqCst);
                if count.fetch_add(1, Ordering::SeqCst) >= 1 {
                    eprintln!("\ninterrupted twice: exiting now (finished rows are in the CSV)");
                    std::process::exit(130);
                }
                eprintln!("\ninterrupt: stopping after cleaning up the current run (Ctrl-C again to quit at once)");
            });
            if let Err(e) = result {
                eprintln!("warning: cannot install the Ctrl-C handler: {e}");
            }
            flag
        })
        .clone()
}

// ------------------------------------------------------------------------------------------
// The campaign loop
// ------------------------------------------------------------------------------------------

/// Options of [`execute`].
#[derive(Clone, Debug, Default)]
pub struct ExecOptions {
    /// Root of the results tree (`results/`).
    pub out_root: PathBuf,
    /// Print the plan only.
    pub dry_run: bool,
    /// Run again configurations whose rows are all failed/invalid/skipped.
    pub retry_failed: bool,
    /// Move an existing `runs.csv` aside and start over.
    pub fresh: bool,
    /// No progress bar, no per-run lines (errors and the summary still print).
    pub quiet: bool,
    /// Command line, for the manifest.
    pub command: String,
}

/// What a campaign session did.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ExecSummary {
    /// Campaign folder.
    pub dir: PathBuf,
    /// Rows written, skipped, ... (also recorded in the manifest's session).
    pub counts: manifest::SessionCounts,
    /// Wall time of the session.
    pub wall: Duration,
}

impl ExecSummary {
    /// Closing summary lines.
    pub fn report(&self) -> String {
        format!(
            "{}: {} rows written ({} ok, {} skipped, {} failed, {} invalid; {} oversubscribed), \
             {} already done of {} planned, wall time {}",
            if self.counts.interrupted { "interrupted" } else { "done" },
            self.counts.written,
            self.counts.ok,
            self.counts.skipped,
            self.counts.failed,
            self.counts.invalid,
            self.counts.oversubscribed,
            self.counts.already_done,
            self.counts.planned,
            humantime::format_duration(Duration::from_secs(self.wall.as_secs()))
        )
    }
}

/// Rough relative cost of a run, for the progress bar's ETA.
fn cost(spec: &RunSpec) -> u64 {
    let p = scenario_size(&spec.scenario, spec.model).map_or(1000, |s| s.particles);
    let steps = spec.budget.step_limit.unwrap_or(300) + 3; // + set-up, in step equivalents
    let f = if spec.opt == OptLevel::O0 { 6 } else { 1 };
    (p / 1000).max(1) * steps * f
}

/// The campaign folder: `<out_root>/<fingerprint>/<campaign id>`.
pub fn campaign_dir(out_root: &Path, machine: &Machine, campaign: &Campaign) -> PathBuf {
    out_root.join(manifest::fingerprint(machine)).join(&campaign.id)
}

/// Run (or resume) `campaign` on `machine` with `runner`, appending a row after every run.
pub fn execute(
    campaign: &Campaign,
    machine: &Machine,
    solvers: &[Solver],
    runner: &mut dyn Runner,
    opts: &ExecOptions,
    interrupted: &AtomicBool,
) -> Result<ExecSummary> {
    let t0 = Instant::now();
    for p in &campaign.pins {
        machine.check_policy(p).with_context(|| format!("pinning policy {p}"))?;
    }
    let dir = campaign_dir(&opts.out_root, machine, campaign);
    let csv_path = dir.join("runs.csv");
    let order = campaign.ordered(campaign.seed);
    let existing = if csv_path.is_file() && !opts.fresh { read_rows(&csv_path)? } else { Vec::new() };
    let done = done_keys(&existing, opts.retry_failed);
    let todo: Vec<(usize, RunSpec)> =
        order.iter().cloned().enumerate().filter(|(_, r)| !done.contains(&r.key())).collect();
    let mut summary = ExecSummary {
        dir: dir.clone(),
        counts: manifest::SessionCounts {
            planned: order.len(),
            already_done: order.len() - todo.len(),
            ..Default::default()
        },
        ..ExecSummary::default()
    };
    let usable = machine.usable_pus().len();

    if opts.dry_run {
        use std::io::Write as _;
        let mut out = std::io::stdout().lock();
        writeln!(
            out,
            "campaign {} ({} runs, {} already done, seed {}) -> {}",
            campaign.id,
            order.len(),
            summary.counts.already_done,
            campaign.seed,
            csv_path.display()
        )?;
        for (i, r) in &todo {
            let pl = machine.place(&r.pin, r.threads)?;
            let est = estimate_memory(&r.scenario, r.model, r.strategy, r.threads);
            let verdict = memory_verdict(est, available_memory(), campaign.mem_limit);
            writeln!(
                out,
                "{:>4}  {:<40} {:<12} cpus {:<16} mem {:>9}{}{}",
                i,
                r.describe(),
                budget_label(r),
                if pl.cpus.is_empty() { "-".to_string() } else { format_cpu_list(&pl.cpus) },
                human_bytes(est),
                if pl.oversubscribed { "  oversubscribed" } else { "" },
                verdict.map(|v| format!("  SKIP ({v})")).unwrap_or_default()
            )?;
        }
        summary.wall = t0.elapsed();
        return Ok(summary);
    }

    std::fs::create_dir_all(&dir).with_context(|| format!("cannot create the output folder {}", dir.display()))?;
    if opts.fresh && csv_path.is_file() {
        let aside = dir.join(format!(
            "runs.csv.{}.bak",
            std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map_or(0, |d| d.as_secs())
        ));
        std::fs::rename(&csv_path, &aside).with_context(|| format!("cannot move {} aside", csv_path.display()))?;
        eprintln!("--fresh: moved the old runs.csv to {}", aside.display());
    }
    let mut log = CsvLog::open(&csv_path)?;
    let json_dir = dir.join("json");
    std::fs::create_dir_all(&json_dir).with_context(|| format!("cannot create {}", json_dir.display()))?;

    // Manifest and topology, once per campaign (a session entry per invocation).
    let ws = workspace_root();
    let git = manifest::git_info(ws.as_deref());
    let binaries: Vec<BinaryInfo> = solvers.iter().map(Solver::info).collect();
    let manifest_path = dir.join("manifest.json");
    let machine_info = manifest::machine_info(machine);
    let mut man = match manifest::read(&manifest_path) {
        Ok(m) => m,
        Err(_) => Manifest {
            manifest_version: manifest::MANIFEST_VERSION,
            campaign_id: campaign.id.clone(),
            campaign: Value::Null,
            machine: machine_info.clone(),
            software: manifest::software_info(ws.as_deref(), binaries.clone()),
            sessions: Vec::new(),
        },
    };
    man.campaign = serde_json::to_value(campaign)?;
    man.machine = machine_info;
    man.software = manifest::software_info(ws.as_deref(), binaries.clone());
    man.sessions.push(Session {
        started: manifest::now_rfc3339(),
        command: opts.command.clone(),
        seed: campaign.seed,
        counts: summary.counts,
        binaries,
        git: git.clone(),
        ..Session::default()
    });
    manifest::write(&manifest_path, &man)?;
    if machine.is_this_system {
        match crate::topology::export_xml() {
            Ok(xml) => mpm_cli::atomic::write_atomic(&dir.join("topology.xml"), xml.as_bytes())?,
            Err(e) => eprintln!("warning: no topology.xml: {e:#}"),
        }
    }

    let show = !opts.quiet;
    let over: Vec<usize> = {
        let mut t: Vec<usize> = todo
            .iter()
            .filter(|(_, r)| machine.place(&r.pin, r.threads).is_ok_and(|p| p.oversubscribed))
            .map(|(_, r)| r.threads)
            .collect();
        t.sort_unstable();
        t.dedup();
        t
    };
    if !over.is_empty() {
        eprintln!(
            "note: {} usable PU(s) here; runs with {} threads are oversubscribed (time sharing, \
             not scaling): their rows are flagged `oversubscribed`",
            usable,
            over.iter().map(|t| t.to_string()).collect::<Vec<_>>().join("/")
        );
    }
    if todo.is_empty() {
        eprintln!("campaign {}: all {} runs already recorded; nothing to do", campaign.id, order.len());
    }

    let total_cost: u64 = todo.iter().map(|(_, r)| cost(r)).sum();
    let pb = if show && !todo.is_empty() {
        ProgressBar::with_draw_target(Some(total_cost), ProgressDrawTarget::stderr())
    } else {
        ProgressBar::hidden()
    };
    pb.set_style(
        ProgressStyle::with_template("[{elapsed_precise}] {bar:24.cyan/blue} {prefix} ETA {eta} | {wide_msg}")
            .expect("valid template")
            .progress_chars("=> "),
    );
    pb.enable_steady_tick(Duration::from_millis(500));
    let solver_of: HashMap<OptLevel, &Solver> = solvers.iter().map(|s| (s.opt, s)).collect();
    let mut attempts: HashMap<RunKey, usize> = HashMap::new();
    for r in &existing {
        *attempts.entry(r.key()).or_default() += 1;
    }

    for (n, (order_index, spec)) in todo.iter().enumerate() {
        if interrupted.load(Ordering::SeqCst) {
            summary.counts.interrupted = true;
            break;
        }
        pb.set_prefix(format!("run {}/{} ({} left)", n + 1, todo.len(), todo.len() - n));
        pb.set_message(spec.describe());
        let solver =
            *solver_of.get(&spec.opt).ok_or_else(|| anyhow!("no solver binary for optimisation level {}", spec.opt))?;
        let placement = machine.place(&spec.pin, spec.threads)?;
        let attempt = attempts.entry(spec.key()).or_default();
        let run_id = format!("{}-a{}", spec.key().0, *attempt);
        *attempt += 1;
        let estimate = estimate_memory(&spec.scenario, spec.model, spec.strategy, spec.threads);
        let mut row = base_row(campaign, machine, &git, solver, spec, &placement.cpus, placement.oversubscribed);
        row.run_id = run_id.clone();
        row.order_index = *order_index;
        row.mem_estimate_bytes = estimate;

        if let Some(reason) = memory_verdict(estimate, available_memory(), campaign.mem_limit) {
            row.status = Status::Skipped;
            row.reason = reason;
        } else {
            let req = RunRequest {
                spec: spec.clone(),
                scenario: campaign.scenario.clone(),
                binary: solver.path.clone(),
                cpus: (!matches!(spec.pin, PinPolicy::None)).then(|| placement.cpus.clone()),
                json_path: json_dir.join(format!("{run_id}.json")),
                timeout: campaign.timeout,
            };
            let out = runner.run(&req);
            if out.interrupted || interrupted.load(Ordering::SeqCst) {
                summary.counts.interrupted = true;
                let _ = std::fs::remove_file(&req.json_path);
                break;
            }
            fill_from_output(&mut row, &req, &out);
        }
        row.timestamp = manifest::now_rfc3339();
        log.append(&row)?;
        summary.counts.written += 1;
        match row.status {
            Status::Ok => summary.counts.ok += 1,
            Status::Skipped => summary.counts.skipped += 1,
            Status::Failed => summary.counts.failed += 1,
            Status::Invalid => summary.counts.invalid += 1,
        }
        if row.oversubscribed {
            summary.counts.oversubscribed += 1;
        }
        if show {
            let line = format!(
                "[{}/{}] {} : {}{}",
                n + 1,
                todo.len(),
                spec.describe(),
                row.status.as_str(),
                match (row.status, row.wall_s) {
                    (Status::Ok, Some(w)) =>
                        format!(" ({w:.2} s solver, {:.1} s process)", row.process_wall_s.unwrap_or(0.0)),
                    _ if !row.reason.is_empty() => format!(" ({})", row.reason),
                    _ => String::new(),
                }
            );
            if pb.is_hidden() {
                eprintln!("{line}");
            } else {
                pb.println(line);
            }
        }
        pb.inc(cost(spec));
    }
    pb.finish_and_clear();
    if interrupted.load(Ordering::SeqCst) {
        summary.counts.interrupted = true;
    }
    summary.wall = t0.elapsed();
    if let Some(s) = man.sessions.last_mut() {
        s.finished = manifest::now_rfc3339();
        s.counts = summary.counts;
    }
    manifest::write(&manifest_path, &man)?;
    debug_assert_eq!(log.path(), csv_path.as_path());
    Ok(summary)
}

fn budget_label(r: &RunSpec) -> String {
    match (r.budget.step_limit, r.budget.end_time) {
        (Some(n), _) => format!("{n} steps (w{})", r.budget.warmup),
        (None, Some(t)) => format!("to {t:e} s (w{})", r.budget.warmup),
        _ => "unbounded".into(),
    }
}

/// Keys of configurations that need no new run.
fn done_keys(rows: &[Row], retry_failed: bool) -> HashSet<RunKey> {
    rows.iter().filter(|r| !retry_failed || r.status == Status::Ok).map(Row::key).collect()
}

fn base_row(
    campaign: &Campaign,
    machine: &Machine,
    git: &manifest::GitInfo,
    solver: &Solver,
    spec: &RunSpec,
    cpus: &[usize],
    oversubscribed: bool,
) -> Row {
    let size = scenario_size(&spec.scenario, spec.model);
    Row {
        schema_version: SCHEMA_VERSION,
        campaign_id: campaign.id.clone(),
        git_commit: git.commit.clone(),
        git_dirty: git.dirty,
        machine_id: manifest::fingerprint(machine),
        binary_sha256: solver.sha256.chars().take(16).collect(),
        seed: campaign.seed,
        scenario: campaign.scenario.clone(),
        model: spec.model,
        particles: size.map(|s| s.particles),
        nodes: size.map(|s| s.nodes),
        grid_mode: spec.grid.clone(),
        strategy: spec.strategy.to_string(),
        opt_level: spec.opt.to_string(),
        threads: spec.threads,
        pin_policy: spec.pin.label(),
        requested_cpus: cpus_cell(cpus),
        oversubscribed,
        rep: spec.rep,
        warmup_steps: spec.budget.warmup,
        step_limit: spec.budget.step_limit,
        end_time_s: spec.budget.end_time,
        ..Row::default()
    }
}

fn f64_of(v: &Value, k: &str) -> Option<f64> {
    v.get(k).and_then(Value::as_f64)
}

fn u64_of(v: &Value, k: &str) -> Option<u64> {
    v.get(k).and_then(|x| x.as_u64().or_else(|| x.as_f64().filter(|f| *f >= 0.0).map(|f| f.round() as u64)))
}

fn cpus_of(v: &Value, k: &str) -> Option<Vec<usize>> {
    v.get(k)?.as_array().map(|a| a.iter().filter_map(|x| x.as_u64().map(|c| c as usize)).collect())
}

/// Fill a row's measurements and status from a finished child process.
fn fill_from_output(row: &mut Row, req: &RunRequest, out: &RunOutput) {
    row.exit_code = out.exit_code;
    row.process_wall_s = Some(out.process_wall_s);
    let why = |out: &RunOutput| -> String {
        let mut s = out.error.clone().unwrap_or_else(|| match out.exit_code {
            Some(c) => format!("solver exited with code {c}"),
            None => "solver did not finish".into(),
        });
        if !out.stderr_tail.is_empty() {
            s.push_str(": ");
            s.push_str(&out.stderr_tail);
        }
        s
    };
    if out.exit_code != Some(0) || out.error.is_some() {
        row.status = Status::Failed;
        row.reason = why(out);
        return;
    }
    let text = match std::fs::read_to_string(&req.json_path) {
        Ok(t) => t,
        Err(e) => {
            row.status = Status::Failed;
            row.reason = format!("solver exited 0 but wrote no JSON summary ({e})");
            return;
        }
    };
    let v: Value = match serde_json::from_str(&text) {
        Ok(v) => v,
        Err(e) => {
            row.status = Status::Failed;
            row.reason = format!("bad JSON summary: {e}");
            return;
        }
    };
    if let Some(s) = v.get("scenario").and_then(Value::as_str) {
        row.scenario = s.to_string();
    }
    row.particles = u64_of(&v, "particles").or(row.particles);
    row.cells = u64_of(&v, "cells");
    row.nodes = u64_of(&v, "nodes").or(row.nodes);
    row.mean_nodes = f64_of(&v, "mean_nodes");
    if let Some(g) = v.get("grid_mode").and_then(Value::as_str) {
        row.grid_mode = g.to_string();
    }
    row.steps = u64_of(&v, "steps");
    row.sim_time_s = f64_of(&v, "sim_time");
    row.end_reason = v.get("end_reason").and_then(Value::as_str).unwrap_or("").to_string();
    row.dt_first_s = f64_of(&v, "dt_first");
    row.wall_s = f64_of(&v, "wall_s");
    row.grid_stage_s = f64_of(&v, "grid_stage_s");
    row.particle_stage_s = f64_of(&v, "particle_stage_s");
    let sub = v.get("substages").cloned().unwrap_or(Value::Null);
    row.sub_grid_fit_s = f64_of(&sub, "grid_fit");
    row.sub_binning_s = f64_of(&sub, "binning");
    row.sub_scatter_s = f64_of(&sub, "scatter");
    row.sub_assembly_s = f64_of(&sub, "assembly");
    row.sub_grid_update_s = f64_of(&sub, "grid_update");
    row.sub_gather_s = f64_of(&sub, "gather");
    row.sub_remap_scatter_s = f64_of(&sub, "remap_scatter");
    row.sub_remap_assembly_s = f64_of(&sub, "remap_assembly");
    row.sub_stress_update_s = f64_of(&sub, "stress_update");
    row.steady_s_per_step = f64_of(&v, "steady_s_per_step");
    row.ns_per_particle_step = f64_of(&v, "ns_per_particle_step");
    row.particle_steps_per_s = f64_of(&v, "particle_steps_per_s");
    row.worker_busy_s = v
        .get("worker_busy_s")
        .and_then(Value::as_array)
        .map(|a| a.iter().filter_map(Value::as_f64).map(|b| format!("{b:.6}")).collect::<Vec<_>>().join(" "))
        .unwrap_or_default();
    row.load_imbalance = f64_of(&v, "load_imbalance");
    row.peak_rss_bytes = u64_of(&v, "peak_rss_bytes");
    row.kinetic_energy_initial_j = f64_of(&v, "kinetic_energy_initial");
    row.kinetic_energy_j = f64_of(&v, "kinetic_energy");
    row.internal_energy_j = f64_of(&v, "internal_energy");
    row.initial_length_m = f64_of(&v, "initial_length_m");
    row.final_length_m = f64_of(&v, "final_length_m");
    row.face_diameter_m = f64_of(&v, "face_diameter_m");
    row.cloud_front_m = f64_of(&v, "cloud_front_m");
    row.cloud_width_m = f64_of(&v, "cloud_width_m");
    row.failed_particles = u64_of(&v, "failed_particles");
    if v.get("oversubscribed").and_then(Value::as_bool) == Some(true) {
        row.oversubscribed = true;
    }
    let requested = req.cpus.clone().unwrap_or_default();
    let observed = cpus_of(&v, "observed_cpus").unwrap_or_default();
    row.observed_cpus = cpus_cell(&observed);
    if let Some(solver_req) = cpus_of(&v, "requested_cpus") {
        if !requested.is_empty() && solver_req != requested {
            row.status = Status::Invalid;
            row.reason = format!(
                "solver reports requested CPUs [{}], harness asked for [{}]",
                cpus_cell(&solver_req),
                cpus_cell(&requested)
            );
            return;
        }
    }
    if !requested.is_empty() && observed != requested {
        row.status = Status::Invalid;
        row.reason = format!(
            "pinning not honoured: requested CPUs [{}], observed [{}]",
            cpus_cell(&requested),
            cpus_cell(&observed)
        );
        return;
    }
    let energies = [row.kinetic_energy_j, row.internal_energy_j, row.wall_s];
    if energies.iter().any(|e| e.is_some_and(|x| !x.is_finite())) || row.wall_s.is_none() || row.steps.is_none() {
        row.status = Status::Invalid;
        row.reason = "summary lacks wall_s/steps or has non-finite values".into();
        return;
    }
    row.status = Status::Ok;
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn memory_estimates_grow_with_ae_threads_only() {
        let ae1 = estimate_memory("taylor", 4, Strategy::Ae, 1);
        let ae8 = estimate_memory("taylor", 4, Strategy::Ae, 8);
        let dd1 = estimate_memory("taylor", 4, Strategy::Dd, 1);
        let dd8 = estimate_memory("taylor", 4, Strategy::Dd, 8);
        assert_eq!(ae8 - ae1, 7 * (80 * 8_302_185 + BYTES_PER_THREAD));
        assert_eq!(dd8 - dd1, 7 * BYTES_PER_THREAD);
        // The paper's 8 GB machine: Model 4 AE at 8 threads does not fit, DD does.
        assert!(memory_verdict(ae8, Some(8 << 30), None).is_some());
        assert!(memory_verdict(dd8, Some(8 << 30), None).is_none());
        assert!(memory_verdict(ae8, Some(64 << 30), Some(4 << 30)).is_some());
        assert!(memory_verdict(ae1, None, None).is_none());
    }

    #[test]
    fn request_args() {
        let spec = RunSpec {
            scenario: "taylor".into(),
            model: 2,
            strategy: Strategy::Dd,
            opt: OptLevel::O3,
            threads: 2,
            pin: PinPolicy::Close,
            rep: 0,
            grid: "fixed".into(),
            budget: crate::matrix::RunBudget { step_limit: Some(5), end_time: None, warmup: 1 },
        };
        let req = RunRequest {
            spec,
            scenario: "taylor".into(),
            binary: "mpm".into(),
            cpus: Some(vec![0, 1]),
            json_path: "x.json".into(),
            timeout: None,
        };
        let a = req.args().join(" ");
        assert_eq!(
            a,
            "run taylor --model 2 --strategy dd --threads 2 --cpus 0,1 --steps 5 --grid fixed --warmup 1 --json x.json --quiet"
        );
    }
}
