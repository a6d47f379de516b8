//! Running a campaign: the loop that, run by run, checks the memory guard, runs `mpm` as a
//! fresh child process and appends a CSV row, plus the manifest and Ctrl-C handling.
//!
//! * Binaries come from [`super::solver`], each run's process from [`super::process`], the
//!   memory estimate and verdict from [`super::memory`].
//! * Oversubscription: rows with more workers (ranks x threads per rank) than usable PUs are
//!   flagged and the terminal says so once per campaign. A run whose observed CPUs differ
//!   from the requested ones is recorded `invalid`.
//! * Several ranks ([`RunPlan`]): the policy places ranks x threads workers; that CPU set is
//!   the launcher's affinity mask and each rank must be seen on its slice of it.
//! * Ctrl-C / SIGTERM ([`install_interrupt_handler`]): the run in progress is stopped and not
//!   recorded; every finished run is already in the CSV, so the campaign resumes later.
//! * Checkpoints (a campaign's `checkpoint_every`, [`RunCheckpoints`]): each run saves its
//!   state into `<campaign>/checkpoints/<run>/`; an attempt killed, timed out or interrupted
//!   is continued from there by the next attempt (`mpm resume`), the compute time it lost is
//!   booked, and the run's row records its restarts and the time lost.
//! * Where runs run ([`Scheduler`]): here, one child process after another (this loop), or
//!   as Slurm batch jobs ([`super::slurm`]), each running [`RunContext::run_one`] on its node
//!   ([`super::job`]); both append their rows through the same [`Books`].

use super::launcher;
use super::lock::{self, FolderLock};
use super::manifest::{self, BinaryInfo, Manifest, Session};
use super::matrix::{Campaign, PlannedRun};
use super::memory::{available_memory, estimate_run_memory, memory_verdict};
use super::preset::OptLevel;
use super::process::{remove_stale_temp_files, RunOutput, RunRequest, Runner};
use super::record::{
    read_rows, repair_garbage, repair_torn_tail, CsvLog, Measured, Row, RunKey, Status, SCHEMA_VERSION,
};
use super::scheduler::Scheduler;
use super::solver::{workspace_root, Solver};
use super::watch::{HostWatch, WatchSettings};
use crate::machine::fingerprint;
use crate::machine::load::Calibration;
use crate::machine::placement::PinPolicy;
use crate::machine::topology::{format_cpu_list, human_bytes, Machine};
use crate::util::{node_name, now_rfc3339};
use anyhow::{anyhow, bail, Context, Result};
use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};
use mpm_spec::spec::CheckpointOutput;
use mpm_spec::Summary;
use serde::{Deserialize, Serialize};
use std::collections::{HashMap, HashSet};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::{Arc, OnceLock};
use std::time::{Duration, Instant};

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
                    super::process::kill_live_child();
                    super::slurm::cancel_submitted();
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
    /// Also run again configurations whose rows are all `skipped` (by the memory guard);
    /// failed and invalid runs are always run again (a failure is not a result).
    pub retry_failed: bool,
    /// When another process runs a campaign into the same folder: wait for it (else refuse).
    pub wait_lock: bool,
    /// Before the runs, time a short calibration run per optimisation level and print the
    /// campaign's estimated duration ([`estimate_duration`]).
    pub eta: bool,
    /// Move an existing `runs.csv` aside and start over.
    pub fresh: bool,
    /// No progress bar, no per-run lines (errors and the summary still print).
    pub quiet: bool,
    /// Command line, for the manifest.
    pub command: String,
    /// Append to a campaign folder whose rows came from another machine or other solver
    /// binaries (otherwise a new folder is started).
    pub resume_foreign: bool,
    /// Watch the host's load around each run (`None`: the `host_*` columns stay empty).
    pub watch: Option<WatchSettings>,
    /// Where the runs run: here (default) or as Slurm jobs.
    pub scheduler: Scheduler,
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
            "{}: {} rows written ({} ok, {} skipped, {} failed, {} invalid; {} oversubscribed, {} flagged noisy), \
             {} already done of {} planned, wall time {}",
            if self.counts.interrupted {
                "interrupted"
            } else if self.counts.queued > 0 {
                "submitted"
            } else {
                "done"
            },
            self.counts.written,
            self.counts.ok,
            self.counts.skipped,
            self.counts.failed,
            self.counts.invalid,
            self.counts.oversubscribed,
            self.counts.noisy,
            self.counts.already_done,
            self.counts.planned,
            humantime::format_duration(Duration::from_secs(self.wall.as_secs()))
        ) + &self.queued_note()
    }

    /// Under a scheduler, when runs were left behind: where they are and how to collect them.
    fn queued_note(&self) -> String {
        let c = &self.counts;
        let unsubmitted = c.planned.saturating_sub(c.already_done + c.written + c.queued);
        if c.queued == 0 && unsubmitted == 0 || c.interrupted {
            return String::new();
        }
        format!(
            "\n{} run(s) in the Slurm queue (job ids in {}), {unsubmitted} not submitted yet: run the same command \
             again to collect them",
            c.queued,
            self.dir.join(super::slurm::JOBS_FILE).display()
        )
    }
}

/// Rough relative cost of a run, for the progress bar's ETA.
fn cost(run: &PlannedRun) -> u64 {
    let p = run.spec.scenario.size().particles;
    let steps = run.spec.budget.steps.unwrap_or(300) + 3; // + set-up, in step equivalents
    let f = if run.opt == OptLevel::O0 { 6 } else { 1 };
    // A paired run also steps its one-thread reference.
    let paired = if run.spec.paired.is_some() { 2 } else { 1 };
    (p / 1000).max(1) * steps * f * paired
}

/// The campaign folder: `<out_root>/<fingerprint>/<campaign id>` (before the resume rule
/// of [`choose_folder`] picks a numbered sibling).
pub fn campaign_dir(out_root: &Path, machine: &Machine, campaign: &Campaign) -> PathBuf {
    out_root.join(fingerprint::fingerprint(machine)).join(&campaign.id)
}

/// What a session would append under: this machine's fingerprint (none when the runs run
/// on a cluster's nodes, whichever they are) and the solver binaries' hashes (16 hex digits,
/// as in the rows) by optimisation level.
pub struct SessionIdentity {
    /// Machine fingerprint; `None` under Slurm (the rows name their nodes' machines).
    pub fingerprint: Option<String>,
    /// `(opt level, hash prefix)` of each solver binary.
    pub binaries: Vec<(String, String)>,
}

impl SessionIdentity {
    /// Of `machine` and `solvers`.
    pub fn of(machine: &Machine, solvers: &[Solver]) -> Self {
        Self {
            fingerprint: Some(fingerprint::fingerprint(machine)),
            binaries: solvers.iter().map(|s| (s.opt.to_string(), short_hash(&s.sha256))).collect(),
        }
    }

    /// Why rows `rows` (and the campaign's manifest) are not this session's to extend:
    /// another machine or another solver binary. `None` when they match.
    pub fn foreign(&self, rows: &[Row], manifest: Option<&Manifest>) -> Option<String> {
        let machines =
            rows.iter().map(|r| r.id.machine_id.as_str()).chain(manifest.map(|m| m.machine.fingerprint.as_str()));
        if let Some(here) = &self.fingerprint {
            if let Some(other) = machines.filter(|f| !f.is_empty()).find(|f| f != here) {
                return Some(format!("holds results of another machine (fingerprint {other}, this one {here})"));
            }
        }
        for r in rows.iter().filter(|r| !r.id.binary_sha256.is_empty()) {
            if let Some((opt, here)) = self.binaries.iter().find(|(o, _)| *o == r.opt().as_str()) {
                if *here != r.id.binary_sha256 {
                    return Some(format!(
                        "holds results of another {opt} solver binary (sha256 {}..., this one {here}...)",
                        r.id.binary_sha256
                    ));
                }
            }
        }
        None
    }
}

/// The first 16 hex digits of a hash, as recorded in every row.
fn short_hash(sha256: &str) -> String {
    sha256.chars().take(16).collect()
}

/// The folder this session appends to. The resume rule: the campaign's folder
/// `<out_root>/<fingerprint>/<id>` when it is new, or when its rows (and manifest) come from
/// this machine and these solver binaries (any machine and binaries with `--resume-foreign`)
/// and its CSV has this harness's columns; never a reference campaign. Otherwise the first of `<id>-2`, `<id>-3`, ... that qualifies,
/// said in one line.
pub fn choose_folder(
    campaign: &Campaign,
    machine: &Machine,
    who: &SessionIdentity,
    opts: &ExecOptions,
) -> Result<PathBuf> {
    let base = match &opts.scheduler {
        Scheduler::Local => campaign_dir(&opts.out_root, machine, campaign),
        Scheduler::Slurm(s) => opts.out_root.join(s.folder()).join(&campaign.id),
    };
    let mut first_refusal: Option<String> = None;
    for n in 1usize.. {
        let dir = if n == 1 { base.clone() } else { base.with_file_name(format!("{}-{n}", campaign.id)) };
        match refusal(&dir, who, opts)? {
            None => {
                if let Some(why) = first_refusal {
                    eprintln!("note: {} {why}; starting a new campaign in {}", base.display(), dir.display());
                }
                return Ok(dir);
            }
            Some(why) => {
                first_refusal.get_or_insert(why);
            }
        }
    }
    unreachable!("an unbounded search ends at a new folder")
}

/// Why `dir` may not take this session's rows (`None`: it may).
fn refusal(dir: &Path, who: &SessionIdentity, opts: &ExecOptions) -> Result<Option<String>> {
    let mpath = dir.join("manifest.json");
    let manifest = if mpath.is_file() {
        Some(manifest::read(&mpath).with_context(|| {
            format!("cannot tell whether {} may be resumed: move it aside or choose another --out", dir.display())
        })?)
    } else {
        None
    };
    if manifest.as_ref().is_some_and(|m| m.reference) {
        return Ok(Some("is a reference campaign (read-only)".into()));
    }
    if opts.fresh {
        return Ok(None);
    }
    let csv = dir.join("runs.csv");
    let rows = if csv.is_file() { read_rows(&csv)? } else { Vec::new() };
    if csv.is_file() {
        let mut r = csv::Reader::from_path(&csv).with_context(|| format!("cannot open {}", csv.display()))?;
        let header = r.headers().with_context(|| format!("cannot read the header of {}", csv.display()))?;
        if !header.iter().eq(Row::header().iter().map(String::as_str)) {
            let v = rows.first().map_or_else(|| "another".into(), |r| r.id.schema_version.to_string());
            return Ok(Some(format!("was written with CSV schema {v} (this harness writes {SCHEMA_VERSION})")));
        }
    }
    if opts.resume_foreign {
        return Ok(None);
    }
    Ok(who.foreign(&rows, manifest.as_ref()).map(|why| format!("{why} (--resume-foreign appends anyway)")))
}

/// The runs of one invocation: the campaign folder, the rows already there and the runs
/// still to do (with their position in the seeded order).
pub(super) struct Plan {
    /// This process's hold on the folder (none for a dry run): no other campaign writes it.
    _lock: Option<FolderLock>,
    pub(super) dir: PathBuf,
    csv_path: PathBuf,
    planned: usize,
    pub(super) existing: Vec<Row>,
    pub(super) todo: Vec<(usize, PlannedRun)>,
}

impl Plan {
    /// Choose the folder ([`choose_folder`]), read its rows (unless `--fresh`) and leave out
    /// the configurations they already hold (all of them, or only the `ok` ones with
    /// `--retry-failed`).
    fn of(campaign: &Campaign, machine: &Machine, solvers: &[Solver], opts: &ExecOptions) -> Result<Self> {
        let mut who = SessionIdentity::of(machine, solvers);
        if !opts.scheduler.runs_here() {
            who.fingerprint = None;
        }
        let dir = choose_folder(campaign, machine, &who, opts)?;
        // The lock before the rows are read: what this session skips, it skips for good.
        let lock = (!opts.dry_run).then(|| lock::acquire(&dir, opts.wait_lock)).transpose()?;
        let csv_path = dir.join("runs.csv");
        let order = campaign.ordered(campaign.seed);
        if csv_path.is_file() && !opts.fresh && !opts.dry_run {
            repair_torn_tail(&csv_path)?;
            repair_garbage(&csv_path)?;
        }
        let existing = if csv_path.is_file() && !opts.fresh { read_rows(&csv_path)? } else { Vec::new() };
        let done = done_keys(&existing, opts.retry_failed);
        let planned = order.len();
        let todo = order.into_iter().enumerate().filter(|(_, r)| !done.contains(&r.key())).collect();
        Ok(Self { _lock: lock, dir, csv_path, planned, existing, todo })
    }

    /// `--dry-run`: every run to do with its CPUs, memory estimate and the guard's verdict.
    fn print(&self, campaign: &Campaign, machine: &Machine) -> Result<()> {
        use std::io::Write as _;
        let mut out = std::io::stdout().lock();
        writeln!(
            out,
            "campaign {} ({} runs, {} already done, seed {}) -> {}",
            campaign.id,
            self.planned,
            self.planned - self.todo.len(),
            campaign.seed,
            self.csv_path.display()
        )?;
        for (i, r) in &self.todo {
            let pl = RunPlan::of(machine, r)?;
            let est = estimate_run_memory(&r.spec);
            let verdict = memory_verdict(est, available_memory(), campaign.mem_limit);
            writeln!(
                out,
                "{:>4}  {:<48} {:<12} cpus {:<16} mem {:>9}{}{}",
                i,
                r.describe(),
                r.budget_label(),
                if pl.requested().is_empty() { "-".to_string() } else { format_cpu_list(pl.requested()) },
                human_bytes(est),
                if pl.oversubscribed { "  oversubscribed" } else { "" },
                verdict.map(|v| format!("  SKIP ({v})")).unwrap_or_default()
            )?;
        }
        Ok(())
    }

    /// Create the folder (moving an old `runs.csv` aside with `--fresh`) and open the CSV
    /// log and the folder of JSON summaries.
    fn open_folder(&self, fresh: bool, here: bool) -> Result<(CsvLog, PathBuf)> {
        let dir = &self.dir;
        std::fs::create_dir_all(dir).with_context(|| format!("cannot create the output folder {}", dir.display()))?;
        if fresh && self.csv_path.is_file() {
            let aside = dir.join(format!(
                "runs.csv.{}.bak",
                std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map_or(0, |d| d.as_secs())
            ));
            std::fs::rename(&self.csv_path, &aside)
                .with_context(|| format!("cannot move {} aside", self.csv_path.display()))?;
            eprintln!("--fresh: moved the old runs.csv to {}", aside.display());
        }
        let log = CsvLog::open(&self.csv_path)?;
        let json_dir = dir.join("json");
        std::fs::create_dir_all(&json_dir).with_context(|| format!("cannot create {}", json_dir.display()))?;
        // Under a scheduler, jobs on other machines may be writing into json/ now: their pids
        // mean nothing here.
        let stale = remove_stale_temp_files(dir) + if here { remove_stale_temp_files(&json_dir) } else { 0 };
        if stale > 0 {
            eprintln!("note: removed {stale} temporary file(s) left by a killed run in {}", dir.display());
        }
        Ok((log, json_dir))
    }

    /// Say once which thread counts are oversubscribed here (when the runs run here), and
    /// when there is nothing to do.
    fn notes(&self, campaign: &Campaign, machine: &Machine, here: bool) {
        let mut over: Vec<(usize, usize)> = self
            .todo
            .iter()
            .filter(|_| here)
            .filter(|(_, r)| RunPlan::of(machine, r).is_ok_and(|p| p.oversubscribed))
            .map(|(_, r)| (r.spec.ranks, r.spec.threads))
            .collect();
        over.sort_unstable();
        over.dedup();
        if !over.is_empty() {
            let label = |&(ranks, t): &(usize, usize)| if ranks > 1 { format!("{ranks}x{t}") } else { t.to_string() };
            eprintln!(
                "note: {} usable PU(s) here; runs with {} threads are oversubscribed (time sharing, \
                 not scaling): their rows are flagged `oversubscribed`",
                machine.usable_pus().len(),
                over.iter().map(label).collect::<Vec<_>>().join("/")
            );
        }
        if self.todo.is_empty() {
            eprintln!("campaign {}: all {} runs already recorded; nothing to do", campaign.id, self.planned);
        }
    }
}

/// The campaign's `manifest.json` with this invocation's session, and `topology.xml`.
pub(super) struct ManifestLog {
    path: PathBuf,
    manifest: Manifest,
}

impl ManifestLog {
    /// Read (or start) the manifest and append this session (its machine, software,
    /// binaries and planned counts); nothing already recorded is changed. A new campaign
    /// also gets this host's `topology.xml`.
    fn start(
        campaign: &Campaign,
        machine: &Machine,
        solvers: &[Solver],
        opts: &ExecOptions,
        dir: &Path,
        counts: manifest::SessionCounts,
        calibration: Option<Calibration>,
    ) -> Result<Self> {
        let ws = workspace_root();
        let git = manifest::git_info(ws.as_deref());
        let binaries: Vec<BinaryInfo> = solvers.iter().map(Solver::info).collect();
        let path = dir.join("manifest.json");
        let machine_info = fingerprint::machine_info(machine);
        let mut software = manifest::software_info(ws.as_deref(), binaries.clone());
        if campaign.ranks.iter().any(|&r| r > 1) {
            software.mpi_launcher = Some(campaign.launcher.version());
        }
        let mut man = if path.is_file() {
            manifest::read(&path)?
        } else {
            Manifest {
                manifest_version: manifest::MANIFEST_VERSION,
                campaign_id: campaign.id.clone(),
                campaign: serde_json::to_value(campaign)?,
                reference: false,
                machine: machine_info.clone(),
                software: software.clone(),
                sessions: Vec::new(),
                nodes: Default::default(),
            }
        };
        let here = opts.scheduler.runs_here();
        man.sessions.push(Session {
            started: now_rfc3339(),
            command: opts.command.clone(),
            seed: campaign.seed,
            counts,
            binaries,
            git,
            machine: Some(machine_info),
            software: Some(software),
            calibration,
            scheduler: opts.scheduler.describe(),
            ..Session::default()
        });
        manifest::write(&path, &man)?;
        // Under a scheduler the runs' machines are the nodes' (recorded as they report).
        let topo = dir.join("topology.xml");
        if here && machine.is_this_system && !topo.exists() {
            match crate::machine::topology::export_xml() {
                Ok(xml) => mpm_host::atomic::write_atomic(&topo, xml.as_bytes())?,
                Err(e) => eprintln!("warning: no topology.xml: {e:#}"),
            }
        }
        Ok(Self { path, manifest: man })
    }

    /// The git state recorded for this session.
    fn git(&self) -> manifest::GitInfo {
        self.manifest.sessions.last().map(|s| s.git.clone()).unwrap_or_default()
    }

    /// Add the machine of fingerprint `fp` to the manifest's nodes (from
    /// `nodes/<fp>.json`, written by the node that ran a job) when it is not there yet.
    pub(super) fn add_node(&mut self, fp: &str) -> Result<()> {
        if fp.is_empty() || self.manifest.nodes.contains_key(fp) {
            return Ok(());
        }
        let dir = self.path.parent().unwrap_or(Path::new("."));
        let Some(node) = super::job::read_node(dir, fp)? else { return Ok(()) };
        self.manifest.nodes.insert(fp.to_string(), node);
        manifest::write(&self.path, &self.manifest)
    }

    /// Record the session's end and counts.
    fn finish(&mut self, counts: manifest::SessionCounts) -> Result<()> {
        if let Some(s) = self.manifest.sessions.last_mut() {
            s.finished = now_rfc3339();
            s.counts = counts;
        }
        manifest::write(&self.path, &self.manifest)
    }
}

/// The progress bar over the runs to do (its ETA weighted by [`cost`]) and a line per run.
pub(super) struct CampaignProgress {
    bar: ProgressBar,
    show: bool,
    total: usize,
    /// The scheduler's queue as last shown: pending, running, done.
    queue: std::cell::Cell<Option<(usize, usize, usize)>>,
}

impl CampaignProgress {
    fn new(todo: &[(usize, PlannedRun)], show: bool) -> Self {
        let total_cost: u64 = todo.iter().map(|(_, r)| cost(r)).sum();
        let bar = if show && !todo.is_empty() {
            ProgressBar::with_draw_target(Some(total_cost), ProgressDrawTarget::stderr())
        } else {
            ProgressBar::hidden()
        };
        bar.set_style(
            ProgressStyle::with_template("[{elapsed_precise}] {bar:24.cyan/blue} {prefix} ETA {eta} | {wide_msg}")
                .expect("valid template")
                .progress_chars("=> "),
        );
        bar.enable_steady_tick(Duration::from_millis(500));
        Self { bar, show, total: todo.len(), queue: std::cell::Cell::new(None) }
    }

    /// Run `n` (0-based) starts.
    fn start(&self, n: usize, spec: &PlannedRun) {
        self.bar.set_prefix(format!("run {}/{} ({} left)", n + 1, self.total, self.total - n));
        self.bar.set_message(spec.describe());
    }

    /// Under a scheduler: how many runs wait in its queue, run, and are done (without a
    /// terminal, a line whenever that changes).
    pub(super) fn queue(&self, pending: usize, running: usize, done: usize, last: &str) {
        let text = format!("slurm: {pending} pending, {running} running, {done}/{} done", self.total);
        if self.queue.replace(Some((pending, running, done))) != Some((pending, running, done)) && self.bar.is_hidden()
        {
            self.say(&text);
        }
        self.bar.set_prefix(text);
        self.bar.set_message(last.to_string());
    }

    /// Print a line above the bar (or on stderr when it is hidden).
    pub(super) fn say(&self, line: &str) {
        if self.show && self.bar.is_hidden() {
            eprintln!("{line}");
        } else if self.show {
            self.bar.println(line);
        }
    }

    /// Run `n` ended with `row`: its line, and the bar moves on.
    fn ended(&self, n: usize, spec: &PlannedRun, row: &Row) {
        if self.show {
            let line =
                format!(
                    "[{}/{}] {} : {}{}",
                    n + 1,
                    self.total,
                    spec.describe(),
                    row.outcome.status.as_str(),
                    match (row.outcome.status, row.measured.wall_s) {
                        (Status::Ok, Some(w)) =>
                            format!(" ({w:.2} s solver, {:.1} s process)", row.outcome.process_wall_s.unwrap_or(0.0)),
                        _ if !row.outcome.reason.is_empty() => format!(" ({})", row.outcome.reason),
                        _ => String::new(),
                    }
                ) + &if row.host.host_noisy { format!(" [host busy: {}]", row.host.host_noise) } else { String::new() };
            if self.bar.is_hidden() {
                eprintln!("{line}");
            } else {
                self.bar.println(line);
            }
        }
        self.bar.inc(cost(spec));
    }
}

/// Where finished runs go: the CSV, the session's counts, the manifest (the nodes' machines)
/// and the progress bar.
pub(super) struct Books<'a> {
    pub(super) log: &'a mut CsvLog,
    pub(super) counts: &'a mut manifest::SessionCounts,
    pub(super) manifest: &'a mut ManifestLog,
    pub(super) progress: &'a CampaignProgress,
}

impl Books<'_> {
    /// Append `row`, the `n`-th (0-based) run of this invocation to end, count it, add its
    /// machine to the manifest when new, and print its line.
    pub(super) fn record(&mut self, n: usize, spec: &PlannedRun, row: &Row) -> Result<()> {
        self.log.append(row)?;
        count(self.counts, row);
        self.manifest.add_node(&row.id.machine_id)?;
        self.progress.ended(n, spec, row);
        Ok(())
    }
}

/// What every run of one invocation shares: the campaign, the machine the runs run on, the
/// git state, the folder of the runs' files, that of their checkpoints and the interrupt flag.
pub(super) struct RunContext<'a> {
    pub(super) campaign: &'a Campaign,
    pub(super) machine: &'a Machine,
    pub(super) git: manifest::GitInfo,
    pub(super) json_dir: PathBuf,
    /// `<campaign>/checkpoints`: each run's checkpoint folder (with a campaign checkpoint
    /// interval).
    pub(super) checkpoint_root: PathBuf,
    pub(super) interrupted: &'a AtomicBool,
}

/// An attempt of a run that did not finish, as the harness saw it.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct LostAttempt {
    /// When it started and ended, seconds since the Unix epoch.
    pub started_unix_s: f64,
    /// When it ended (killed, timed out, interrupted, failed).
    pub ended_unix_s: f64,
    /// Its compute time after its last checkpoint (all of it when it wrote none), s.
    pub lost_s: f64,
    /// Why it ended.
    pub reason: String,
}

/// A run's checkpoints in its campaign folder: `checkpoints/<label>-<key>/`, the solver's
/// folder (one per planned run, whatever the attempt), and beside it `<...>.attempts.json`,
/// the harness's list of the attempts that did not finish (what they lost), kept across
/// sessions until the run ends `ok`; then both are removed.
#[derive(Clone, Debug)]
pub struct RunCheckpoints {
    /// The solver's checkpoint folder.
    pub dir: PathBuf,
    log: PathBuf,
}

impl RunCheckpoints {
    /// The checkpoints of `run` under `root`.
    pub fn of(root: &Path, run: &PlannedRun) -> Self {
        let name = format!("{}-{}", run.label(), run.key().0);
        Self { dir: root.join(&name), log: root.join(format!("{name}.attempts.json")) }
    }

    /// Whether the folder holds a checkpoint to continue from.
    pub fn resumable(&self) -> bool {
        matches!(mpm_host::checkpoint::newest_header(&self.dir), Ok(Some(_)))
    }

    /// The attempts that did not finish, oldest first.
    pub fn attempts(&self) -> Vec<LostAttempt> {
        std::fs::read_to_string(&self.log).ok().and_then(|t| serde_json::from_str(&t).ok()).unwrap_or_default()
    }

    /// Compute time lost by the attempts that did not finish (s).
    pub fn lost_s(&self) -> f64 {
        self.attempts().iter().map(|a| a.lost_s).sum()
    }

    /// Book an attempt from `started` to `ended` (Unix seconds) that did not finish: it lost
    /// its time after the newest checkpoint it wrote, or all of it.
    pub fn record_loss(&self, started: f64, ended: f64, reason: &str) -> Result<()> {
        let saved_at = mpm_host::checkpoint::newest_header(&self.dir)
            .ok()
            .flatten()
            .map(|(_, h)| h.written_unix_s)
            .filter(|&t| t >= started && t <= ended);
        let lost_s = (ended - saved_at.unwrap_or(started)).max(0.0);
        let mut all = self.attempts();
        all.push(LostAttempt { started_unix_s: started, ended_unix_s: ended, lost_s, reason: reason.into() });
        std::fs::create_dir_all(self.log.parent().unwrap_or(Path::new(".")))?;
        Ok(mpm_host::atomic::write_atomic(&self.log, serde_json::to_string_pretty(&all)?.as_bytes())?)
    }

    /// A finished run needs neither its checkpoints nor its list of attempts.
    pub fn remove(&self) {
        let _ = std::fs::remove_dir_all(&self.dir);
        let _ = std::fs::remove_file(&self.log);
    }
}

impl RunContext<'_> {
    /// One run: skipped by the memory guard, or run by `runner` and recorded from its
    /// summary. `None` when the campaign was interrupted during the run (nothing recorded).
    pub(super) fn run_one(
        &self,
        runner: &mut dyn Runner,
        mut watch: Option<&mut HostWatch>,
        solver: &Solver,
        planned: &PlannedRun,
        order_index: usize,
        run_id: String,
    ) -> Result<Option<Row>> {
        let plan = RunPlan::of(self.machine, planned)?;
        let estimate = estimate_run_memory(&planned.spec);
        let mut row = base_row(self.campaign, self.machine, &self.git, solver, planned, &plan);
        row.id.order_index = order_index;
        row.outcome.mem_estimate_bytes = estimate;
        if let Some(reason) = memory_verdict(estimate, available_memory(), self.campaign.mem_limit) {
            row.outcome.status = Status::Skipped;
            row.outcome.reason = reason;
        } else {
            let launched = planned.spec.ranks > 1;
            let mut req = RunRequest::new(
                planned,
                if launched { None } else { plan.cpus.clone() },
                self.json_dir.join(format!("{run_id}.json")),
                self.json_dir.join(format!("{run_id}.spec.toml")),
            );
            // With checkpoints: into the run's own folder, and continued from it when a
            // checkpoint is there (an earlier attempt was killed, timed out or interrupted).
            let checkpoints = self.campaign.checkpoint_every.map(|every| {
                let c = RunCheckpoints::of(&self.checkpoint_root, planned);
                req.spec.outputs.checkpoint = Some(CheckpointOutput { dir: c.dir.clone(), every });
                req.resume = c.resumable().then(|| c.dir.clone());
                c
            });
            req.binary = solver.path.clone();
            req.launcher = launched.then(|| self.campaign.launcher.expand(planned.spec.ranks, planned.spec.threads));
            req.mask = if launched { plan.cpus.clone() } else { None };
            req.timeout = self.campaign.timeout;
            let probe_cpus = plan.cpus.clone().unwrap_or_default();
            let before = watch.as_deref_mut().map(|w| w.before_run(&probe_cpus));
            let started = mpm_host::clock::unix_now();
            let out = runner.run(&req);
            let ended = mpm_host::clock::unix_now();
            if out.interrupted || self.interrupted.load(Ordering::SeqCst) {
                let _ = std::fs::remove_file(&req.json_path);
                if let Some(c) = &checkpoints {
                    c.record_loss(started, ended, "interrupted")?;
                }
                return Ok(None);
            }
            fill_from_output(&mut row, &req, &out);
            if let Some(c) = &checkpoints {
                if row.outcome.status == Status::Ok {
                    row.outcome.lost_compute_s = Some(c.lost_s());
                    c.remove();
                } else {
                    c.record_loss(started, ended, &row.outcome.reason)?;
                    row.outcome.lost_compute_s = Some(c.lost_s());
                }
            }
            if let (Some(w), Some(b)) = (watch, before) {
                row.set_host(&w.after_run(&probe_cpus, b), self.machine.usable_pus().len());
            }
            row.flag_low_cpu_share();
        }
        row.id.run_id = run_id;
        row.id.timestamp = now_rfc3339();
        Ok(Some(row))
    }
}

/// The campaign's duration, estimated from one short calibration run per optimisation level
/// (Taylor Model 1, serial, 20 steps, 2 of them warm-up: a few seconds): each run costs its
/// set-up (the calibration's, in proportion to the particles) and its steps x particles x the
/// calibration's time per particle-step, over the cores it uses (at 80 % efficiency; an
/// oversubscribed run gets no more than the cores). End-time budgets take their step count
/// from the calibration's time step scaled with the Taylor model's cell size; the impact's
/// steps are not estimated.
pub fn estimate_duration(
    runner: &mut dyn Runner,
    solvers: &[Solver],
    todo: &[(usize, PlannedRun)],
    json_dir: &Path,
    cores: usize,
) -> Result<String> {
    use std::collections::BTreeMap;
    let mut calib: BTreeMap<OptLevel, (f64, f64, f64)> = BTreeMap::new(); // ns per ps, setup s per particle, dt
    for opt in todo.iter().map(|(_, r)| r.opt).collect::<std::collections::BTreeSet<_>>() {
        let solver = solvers.iter().find(|s| s.opt == opt).ok_or_else(|| anyhow!("no {opt} solver"))?;
        let mut run = PlannedRun::taylor(1, mpm_core::Strategy::Serial, opt, 1, 20);
        run.spec.budget.warmup = Some(2);
        let mut req = RunRequest::new(
            &run,
            None,
            json_dir.join(format!("calibration-{opt}.json")),
            json_dir.join(format!("calibration-{opt}.spec.toml")),
        );
        req.binary = solver.path.clone();
        req.timeout = Some(Duration::from_secs(300));
        let out = runner.run(&req);
        let summary = read_summary(&req.json_path);
        let _ = std::fs::remove_file(&req.json_path);
        let _ = std::fs::remove_file(&req.spec_path);
        let s = summary.map_err(|e| anyhow!("the {opt} calibration run: {e}"))?;
        let ns = s.ns_per_particle_step.ok_or_else(|| anyhow!("the {opt} calibration run has no steady steps"))?;
        let setup = (out.process_wall_s - s.wall_s).max(0.0) / s.particles.max(1) as f64;
        calib.insert(opt, (ns, setup, s.dt_first));
    }
    let mut total = 0.0;
    let mut unknown = 0;
    for (_, r) in todo {
        let (ns, setup, dt1) = calib[&r.opt];
        let size = r.spec.scenario.size();
        let p = size.particles as f64;
        let steps = match (r.spec.budget.steps, r.spec.budget.end_time_s, r.spec.scenario) {
            (Some(n), _, _) => n as f64,
            (None, Some(t), mpm_spec::Scenario::Taylor(tb)) => {
                let nz = [48.0, 72.0, 132.0, 264.0][usize::from(tb.model.clamp(1, 4)) - 1];
                t / (dt1 * 48.0 / nz)
            }
            _ => {
                unknown += 1;
                continue;
            }
        };
        let workers = r.total_threads();
        let speed = if workers > 1 { 0.8 * workers.min(cores) as f64 } else { 1.0 };
        // A paired run steps a one-thread reference beside it.
        let reference = if r.spec.paired.is_some() { steps * p * ns * 1e-9 } else { 0.0 };
        total += p * setup + steps * p * ns * 1e-9 / speed + reference;
    }
    let rates: Vec<String> =
        calib.iter().map(|(o, (ns, _, _))| format!("{ns:.0} ns per particle-step at {o}")).collect();
    Ok(format!(
        "estimated duration: about {} for {} run(s){} (from a calibration run of Taylor Model 1, 20 serial steps: {}; \
         a run costs its steps x particles at that rate over its cores, plus its set-up)",
        humantime::format_duration(Duration::from_secs(total.round() as u64)),
        todo.len() - unknown,
        if unknown > 0 { format!(", {unknown} more not estimated (impact end times)") } else { String::new() },
        rates.join(", ")
    ))
}

/// Add a written row to the session's counts.
fn count(counts: &mut manifest::SessionCounts, row: &Row) {
    counts.written += 1;
    match row.outcome.status {
        Status::Ok => counts.ok += 1,
        Status::Skipped => counts.skipped += 1,
        Status::Failed => counts.failed += 1,
        Status::Invalid => counts.invalid += 1,
    }
    if row.placement.oversubscribed {
        counts.oversubscribed += 1;
    }
    if row.host.host_noisy {
        counts.noisy += 1;
    }
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
    let plan = Plan::of(campaign, machine, solvers, opts)?;
    let mut counts = manifest::SessionCounts {
        planned: plan.planned,
        already_done: plan.planned - plan.todo.len(),
        ..Default::default()
    };
    if opts.dry_run {
        plan.print(campaign, machine)?;
        return Ok(ExecSummary { dir: plan.dir, counts, wall: t0.elapsed() });
    }
    let here = opts.scheduler.runs_here();
    plan.notes(campaign, machine, here);
    if plan.todo.is_empty() {
        // Nothing to do: the folder, its manifest and topology stay as they are.
        return Ok(ExecSummary { dir: plan.dir, counts, wall: t0.elapsed() });
    }
    if here && plan.todo.iter().any(|(_, run)| run.spec.ranks > 1) {
        if let Some(why) = runner.launcher_refusal(&campaign.launcher) {
            bail!("{why}");
        }
    }
    let (mut log, json_dir) = plan.open_folder(opts.fresh, here)?;
    // Under a scheduler each job watches its own node.
    let mut watch = opts.watch.filter(|_| here).map(|w| HostWatch::start(w, machine.usable_pus().len()));
    let calibration = watch.as_ref().map(HostWatch::calibration);
    let mut manifest = ManifestLog::start(campaign, machine, solvers, opts, &plan.dir, counts, calibration)?;
    if opts.eta && here {
        match estimate_duration(runner, solvers, &plan.todo, &json_dir, machine.usable_pus().len()) {
            Ok(eta) => eprintln!("{eta}"),
            Err(e) => eprintln!("note: no duration estimate: {e:#}"),
        }
    }
    let progress = CampaignProgress::new(&plan.todo, !opts.quiet);
    let solver_of: HashMap<OptLevel, &Solver> = solvers.iter().map(|s| (s.opt, s)).collect();
    let mut attempts: HashMap<RunKey, usize> = HashMap::new();
    for r in &plan.existing {
        *attempts.entry(r.key()).or_default() += 1;
    }
    let checkpoint_root = plan.dir.join("checkpoints");
    let ctx = RunContext { campaign, machine, git: manifest.git(), json_dir, checkpoint_root, interrupted };
    let mut books = Books { log: &mut log, counts: &mut counts, manifest: &mut manifest, progress: &progress };
    match &opts.scheduler {
        Scheduler::Slurm(slurm) => {
            let settings = super::slurm::Submission { options: slurm, watch: opts.watch, solvers: &solver_of };
            super::slurm::run_jobs(&ctx, &settings, &plan, &mut attempts, &mut books)?;
        }
        Scheduler::Local => {
            for (n, (order_index, spec)) in plan.todo.iter().enumerate() {
                if interrupted.load(Ordering::SeqCst) {
                    books.counts.interrupted = true;
                    break;
                }
                progress.start(n, spec);
                let solver = solver_for(&solver_of, spec)?;
                let run_id = next_run_id(&mut attempts, spec);
                let Some(row) = ctx.run_one(runner, watch.as_mut(), solver, spec, *order_index, run_id)? else {
                    books.counts.interrupted = true;
                    break;
                };
                books.record(n, spec, &row)?;
            }
        }
    }
    progress.bar.finish_and_clear();
    counts.interrupted |= interrupted.load(Ordering::SeqCst);
    let wall = t0.elapsed();
    manifest.finish(counts)?;
    debug_assert_eq!(log.path(), plan.csv_path.as_path());
    Ok(ExecSummary { dir: plan.dir, counts, wall })
}

/// The solver binary of `run`'s optimisation level.
pub(super) fn solver_for<'s>(solvers: &HashMap<OptLevel, &'s Solver>, run: &PlannedRun) -> Result<&'s Solver> {
    solvers.get(&run.opt).copied().ok_or_else(|| anyhow!("no solver binary for optimisation level {}", run.opt))
}

/// The id of `run`'s next attempt (`<label>-<key>-a<attempt>`), counting it.
pub(super) fn next_run_id(attempts: &mut HashMap<RunKey, usize>, run: &PlannedRun) -> String {
    let key = run.key();
    let attempt = attempts.entry(key.clone()).or_default();
    let id = format!("{}-{}-a{}", run.label(), key.0, *attempt);
    *attempt += 1;
    id
}

/// Keys of configurations that need no new run: those with an `ok` row, and those the
/// memory guard skipped (unless `retry_skipped`). A failed or invalid run is not a result:
/// it is run again.
fn done_keys(rows: &[Row], retry_skipped: bool) -> HashSet<RunKey> {
    rows.iter()
        .filter(|r| r.outcome.status == Status::Ok || (r.outcome.status == Status::Skipped && !retry_skipped))
        .map(Row::key)
        .collect()
}

/// Where a run's workers go: the policy's placement of ranks x threads workers.
#[derive(Clone, Debug, PartialEq)]
pub struct RunPlan {
    /// The CPUs the run is pinned to (`None` with the policy `none`): one process's `--cpus`
    /// in worker order, or with several ranks the launcher's affinity mask, ascending and
    /// without repeats (each rank pins to its slice of it in this order).
    pub cpus: Option<Vec<usize>>,
    /// More workers than usable PUs, or two workers on one CPU.
    pub oversubscribed: bool,
}

impl RunPlan {
    /// The plan of `run` on `machine`.
    pub fn of(machine: &Machine, run: &PlannedRun) -> Result<Self> {
        let placement = machine.place_ranks(&run.pin, run.spec.ranks, run.spec.threads)?;
        let cpus = (!matches!(run.pin, PinPolicy::None)).then_some(placement.cpus);
        Ok(Self { cpus, oversubscribed: placement.oversubscribed })
    }

    /// What the row records as requested: `cpus`, or nothing.
    pub fn requested(&self) -> &[usize] {
        self.cpus.as_deref().unwrap_or_default()
    }
}

/// The row of `run` before it runs anywhere: its campaign, software and seed.
pub(super) fn planned_row(campaign: &Campaign, git: &manifest::GitInfo, solver: &Solver, run: &PlannedRun) -> Row {
    let mut row = Row::planned(run.clone());
    row.id.campaign_id = campaign.id.clone();
    row.id.git_commit = git.commit.clone();
    row.id.git_dirty = git.dirty;
    row.id.binary_sha256 = short_hash(&solver.sha256);
    row.id.seed = campaign.seed;
    row
}

/// The row of `run` about to run on `machine` (this node) as `plan` places it.
fn base_row(
    campaign: &Campaign,
    machine: &Machine,
    git: &manifest::GitInfo,
    solver: &Solver,
    run: &PlannedRun,
    plan: &RunPlan,
) -> Row {
    let mut row = planned_row(campaign, git, solver, run);
    row.id.machine_id = fingerprint::fingerprint(machine);
    row.id.node = node_name();
    row.placement.requested_cpus = plan.requested().to_vec();
    row.placement.oversubscribed = plan.oversubscribed;
    row
}

/// Fill a row's measurements and status from a finished child process: failed when the
/// process failed or left no readable summary, invalid when the summary contradicts the
/// request (another spec than the one asked, CPUs not as placed, non-finite figures), ok
/// otherwise.
fn fill_from_output(row: &mut Row, req: &RunRequest, out: &RunOutput) {
    let o = &mut row.outcome;
    o.exit_code = out.exit_code;
    o.process_wall_s = Some(out.process_wall_s);
    if out.exit_code != Some(0) || out.error.is_some() {
        o.status = Status::Failed;
        o.reason = process_failure(out);
        if let Some(hint) = req.launcher.as_ref().and(launcher::failure_hint(&out.stderr_tail)) {
            o.reason = format!("{hint}: {}", o.reason);
        }
        return;
    }
    let summary = match read_summary(&req.json_path) {
        Ok(s) => s,
        Err(reason) => {
            o.status = Status::Failed;
            o.reason = reason;
            return;
        }
    };
    row.measured = Measured::of(&summary);
    let ranks = summary.ranks.as_deref().unwrap_or_default();
    row.placement.observed_cpus = if ranks.is_empty() {
        summary.observed_cpus.clone()
    } else {
        ranks.iter().flat_map(|r| r.cpus.iter().copied()).collect()
    };
    row.placement.rank_cpus = ranks.iter().map(|r| r.cpus.clone()).collect();
    row.placement.oversubscribed |= summary.oversubscribed || ranks.iter().any(|r| r.oversubscribed);
    let checked = check_spec(&summary, &req.spec).and_then(|()| {
        if req.spec.ranks > 1 {
            check_ranks(&summary, req.spec.ranks, req.spec.threads, req.mask.as_deref().unwrap_or_default())
        } else {
            check_summary(&summary, &req.spec.cpus.clone().unwrap_or_default())
        }
    });
    match checked {
        Ok(()) => row.outcome.status = Status::Ok,
        Err(reason) => {
            row.outcome.status = Status::Invalid;
            row.outcome.reason = reason;
        }
    }
}

/// Whether the solver ran the spec it was given: its summary echoes the spec it ran.
fn check_spec(s: &Summary, asked: &mpm_spec::RunSpec) -> Result<(), String> {
    match &s.spec {
        Some(ran) if ran == asked => Ok(()),
        Some(ran) => Err(format!(
            "the solver ran another spec than the one asked (asked {}, ran {}): is the solver binary older than the \
             harness?",
            asked.canonical(),
            ran.canonical()
        )),
        None => Err("the summary has no spec: the solver binary is older than the harness; rebuild it".into()),
    }
}

/// Why a child process failed: its error or exit code, and the tail of its standard error.
fn process_failure(out: &RunOutput) -> String {
    let mut s = out.error.clone().unwrap_or_else(|| match out.exit_code {
        Some(c) => format!("solver exited with code {c}"),
        None => "solver did not finish".into(),
    });
    if !out.stderr_tail.is_empty() {
        s.push_str(": ");
        s.push_str(&out.stderr_tail);
    }
    s
}

/// The JSON summary a successful `mpm` run wrote.
fn read_summary(path: &Path) -> Result<Summary, String> {
    let text = std::fs::read_to_string(path).map_err(|e| format!("solver exited 0 but wrote no JSON summary ({e})"))?;
    serde_json::from_str(&text).map_err(|e| format!("bad JSON summary: {e}"))
}

/// Whether the summary of a run over `ranks` ranks of `threads` threads is a valid
/// measurement: it reports that many ranks, each with its workers; pinned (`mask` not
/// empty), every worker is inside the mask, and when the mask has room for all workers the
/// ranks took consecutive slices of it in rank order (disjoint CPUs, as placed).
fn check_ranks(s: &Summary, ranks: usize, threads: usize, mask: &[usize]) -> Result<(), String> {
    let reports = s.ranks.as_deref().unwrap_or_default();
    if reports.len() != ranks {
        return Err(format!(
            "asked for {ranks} ranks, the summary reports {} (does the launcher start `{{ranks}}` processes, and \
             was mpm built with the mpi feature?)",
            reports.len()
        ));
    }
    if let Some(r) = reports.iter().find(|r| r.cpus.len() != threads) {
        return Err(format!("rank {} reports {} worker CPUs, asked for {threads} threads", r.rank, r.cpus.len()));
    }
    if mask.is_empty() {
        return check_summary(s, &[]);
    }
    let observed: Vec<usize> = reports.iter().flat_map(|r| r.cpus.iter().copied()).collect();
    if let Some(c) = observed.iter().find(|c| !mask.contains(c)) {
        return Err(format!(
            "pinning not honoured: a rank ran on CPU {c}, outside the CPUs [{}] given to the launcher \
             (a launcher that binds ranks itself overrides them: use --bind-to none, or --bind none)",
            list(mask)
        ));
    }
    if mask.len() >= ranks * threads && observed != mask[..ranks * threads] {
        return Err(format!(
            "pinning not honoured: ranks should take consecutive slices of [{}], observed [{}]",
            list(mask),
            list(&observed)
        ));
    }
    check_summary(s, &[])
}

/// Whether a summary is a valid measurement of what was asked: the CPUs the harness
/// requested (empty when not pinned) are the ones the solver was asked for and observed,
/// and the figures are finite.
fn check_summary(s: &Summary, requested: &[usize]) -> Result<(), String> {
    if !requested.is_empty() && s.requested_cpus != requested {
        return Err(format!(
            "solver reports requested CPUs [{}], harness asked for [{}]",
            list(&s.requested_cpus),
            list(requested)
        ));
    }
    if !requested.is_empty() && s.observed_cpus != requested {
        return Err(format!(
            "pinning not honoured: requested CPUs [{}], observed [{}]",
            list(requested),
            list(&s.observed_cpus)
        ));
    }
    if [s.kinetic_energy, s.internal_energy, s.wall_s].iter().any(|x| !x.is_finite()) {
        return Err("summary has non-finite values (wall_s or energies)".into());
    }
    Ok(())
}

/// A CPU list for a message: `0 1 2`.
fn list(cpus: &[usize]) -> String {
    cpus.iter().map(|c| c.to_string()).collect::<Vec<_>>().join(" ")
}

#[cfg(test)]
mod tests {
    use super::*;
    use mpm_core::Strategy;
    use mpm_spec::scenario::TaylorSpec;
    use mpm_spec::summary::RankReport;
    use mpm_spec::{RunSpec, Scenario};

    /// The compute time an attempt lost: its time after the newest checkpoint it wrote, all
    /// of it when it wrote none (a checkpoint of an earlier attempt does not count), summed
    /// over the attempts until the run is removed.
    #[test]
    fn lost_compute_is_the_time_after_the_last_checkpoint_of_each_attempt() {
        let dir = tempfile::tempdir().unwrap();
        let run = spec(1, 1, PinPolicy::CLOSE);
        let c = RunCheckpoints::of(dir.path(), &run);
        assert!(c.dir.starts_with(dir.path()) && c.dir.to_string_lossy().contains(&run.key().0));
        assert!(!c.resumable());
        assert_eq!(c.lost_s(), 0.0);
        // An attempt that wrote no checkpoint lost all of it.
        c.record_loss(100.0, 160.0, "timed out after 1m").unwrap();
        assert_eq!(c.lost_s(), 60.0);
        // An attempt that wrote one (now, by the clock) lost only its time after it.
        let folder = mpm_host::checkpoint::Folder::new(&c.dir);
        let partial = folder.begin(40).unwrap();
        let meta = mpm_host::checkpoint::Meta {
            rank: 0,
            ranks: 1,
            step: 40,
            time_s: 1e-6,
            spec_key: "k".into(),
            binary_sha256: "b".into(),
        };
        let p = mpm_core::Particles::default();
        mpm_host::checkpoint::write_file(&partial.join("rank-0000.ckpt"), &meta, toml::Table::new(), &p, None).unwrap();
        folder.commit(40).unwrap();
        assert!(c.resumable());
        let now = mpm_host::clock::unix_now();
        c.record_loss(now - 100.0, now + 5.0, "killed by signal 9").unwrap();
        let lost = c.lost_s() - 60.0;
        assert!((4.0..6.0).contains(&lost), "{lost}");
        // A later attempt that wrote none: its whole time, though a checkpoint exists.
        c.record_loss(now + 10.0, now + 30.0, "interrupted").unwrap();
        assert!((c.lost_s() - 60.0 - lost - 20.0).abs() < 1e-9);
        assert_eq!(
            c.attempts().iter().map(|a| a.reason.as_str()).collect::<Vec<_>>(),
            ["timed out after 1m", "killed by signal 9", "interrupted"]
        );
        c.remove();
        assert!(!c.dir.exists() && c.attempts().is_empty());
    }

    fn spec(ranks: usize, threads: usize, pin: PinPolicy) -> PlannedRun {
        let mut spec = RunSpec::new(Scenario::Taylor(TaylorSpec::model(1))).unwrap();
        spec.strategy = Strategy::DomainDecomposition;
        spec.threads = threads;
        spec.ranks = ranks;
        spec.budget.steps = Some(5);
        spec.budget.warmup = Some(1);
        PlannedRun { spec, model: 1, opt: OptLevel::O3, pin, launcher: None, rep: 0 }
    }

    /// Oversubscription counts ranks x threads per rank against the usable PUs, and the
    /// launcher's mask is the placement of all workers, ascending.
    #[test]
    fn ranks_times_threads_are_placed_and_counted() {
        let laptop = Machine::synthetic("pack:1 core:2 pu:1").unwrap();
        let p = RunPlan::of(&laptop, &spec(2, 1, PinPolicy::CLOSE)).unwrap();
        assert_eq!((p.cpus, p.oversubscribed), (Some(vec![0, 1]), false));
        let p = RunPlan::of(&laptop, &spec(1, 2, PinPolicy::CLOSE)).unwrap();
        assert_eq!((p.cpus, p.oversubscribed), (Some(vec![0, 1]), false));
        // 2 ranks x 2 threads = 4 workers on 2 cores: flagged, though each rank alone fits.
        let p = RunPlan::of(&laptop, &spec(2, 2, PinPolicy::CLOSE)).unwrap();
        assert_eq!((p.cpus, p.oversubscribed), (Some(vec![0, 1]), true));
        let p = RunPlan::of(&laptop, &spec(2, 2, PinPolicy::None)).unwrap();
        assert_eq!((p.requested().to_vec(), p.cpus, p.oversubscribed), (vec![], None, true));
        // Two sockets of four cores: spread puts the ranks' workers on both sockets, close on one.
        let two = Machine::synthetic("pack:2 core:4 pu:1").unwrap();
        assert_eq!(RunPlan::of(&two, &spec(2, 2, PinPolicy::SPREAD)).unwrap().cpus, Some(vec![0, 2, 4, 6]));
        assert_eq!(RunPlan::of(&two, &spec(2, 2, PinPolicy::CLOSE)).unwrap().cpus, Some(vec![0, 1, 2, 3]));
        assert!(!RunPlan::of(&two, &spec(2, 4, PinPolicy::CLOSE)).unwrap().oversubscribed);
        assert!(RunPlan::of(&two, &spec(3, 3, PinPolicy::CLOSE)).unwrap().oversubscribed);
    }

    fn summary(cpus: &[&[usize]]) -> Summary {
        let ranks = cpus
            .iter()
            .enumerate()
            .map(|(rank, c)| RankReport { rank, cpus: c.to_vec(), ..RankReport::default() })
            .collect();
        Summary { ranks: Some(ranks), wall_s: 1.0, ..Summary::default() }
    }

    #[test]
    fn ranks_must_be_seen_on_their_slices_of_the_mask() {
        let mask = [0, 1, 2, 3];
        assert_eq!(check_ranks(&summary(&[&[0, 1], &[2, 3]]), 2, 2, &mask), Ok(()));
        // Not pinned: only the rank count and the workers per rank are checked.
        assert_eq!(check_ranks(&summary(&[&[3, 3], &[0, 0]]), 2, 2, &[]), Ok(()));
        let err = |s: &Summary, ranks, threads, mask: &[usize]| check_ranks(s, ranks, threads, mask).unwrap_err();
        assert!(err(&summary(&[&[0, 1], &[2, 3]]), 3, 2, &mask).contains("asked for 3 ranks"));
        assert!(err(&summary(&[&[0], &[2]]), 2, 2, &mask).contains("2 threads"));
        // A launcher that bound the ranks itself, elsewhere.
        assert!(err(&summary(&[&[0, 1], &[4, 5]]), 2, 2, &mask).contains("outside the CPUs"));
        // Both ranks on the same slice although the mask had room for both.
        assert!(err(&summary(&[&[0, 1], &[0, 1]]), 2, 2, &mask).contains("consecutive slices"));
        // Too small a mask (oversubscribed): sharing inside it is accepted.
        assert_eq!(check_ranks(&summary(&[&[0, 1], &[0, 1]]), 2, 2, &[0, 1]), Ok(()));
    }

    /// The `ranks` section fills the hybrid columns: CPUs rank by rank, memory summed, the
    /// slowest rank's exchange per step, bytes and messages of all ranks per step, and the
    /// waiting of the rank that waited most when every rank measured it (--split-wait).
    #[test]
    fn rank_reports_fill_the_hybrid_columns() {
        let mut s = summary(&[&[0], &[1]]);
        s.steps = 10;
        s.wall_s = 2.0;
        s.oversubscribed = false;
        let reports = s.ranks.as_mut().unwrap();
        for (i, r) in reports.iter_mut().enumerate() {
            r.particles = 100 + i;
            r.migrated = 2;
            r.busy_s = 1.0 + i as f64;
            r.peak_rss_bytes = Some(1000);
            r.exchange.halo_bytes = 800;
            r.exchange.reduction_bytes = 200;
            r.exchange.halo_messages = 20;
            r.exchange.seconds = 0.1 * (i + 1) as f64;
        }
        s.ranks.as_mut().unwrap()[1].oversubscribed = true;
        let m = Measured::of(&s);
        assert_eq!(m.rank_particles, [100, 101]);
        assert_eq!(m.migrated_particles, Some(4));
        assert_eq!(m.peak_rss_sum_bytes, Some(2000));
        assert_eq!(m.comm_bytes_per_step, Some(200.0));
        assert_eq!(m.comm_messages_per_step, Some(4.0));
        assert!((m.comm_s_per_step.unwrap() - 0.02).abs() < 1e-15);
        assert!((m.comm_frac.unwrap() - 0.1).abs() < 1e-15);
        assert!((m.rank_busy_imbalance.unwrap() - 2.0 / 1.5).abs() < 1e-12);
        assert_eq!((m.wait_s_per_step, m.wait_frac), (None, None), "run without --split-wait");
        let mut row = Row::planned(spec(2, 1, PinPolicy::CLOSE));
        row.measured = m;
        assert!(row.comm_includes_wait());
        // With --split-wait: the waiting of the rank that waited most (rank 0 here, while
        // rank 1 communicated most), apart from the communication.
        for (i, r) in s.ranks.as_mut().unwrap().iter_mut().enumerate() {
            r.exchange.wait_seconds = Some(0.3 - 0.1 * i as f64);
        }
        row.measured = Measured::of(&s);
        assert!((row.measured.wait_s_per_step.unwrap() - 0.03).abs() < 1e-15);
        assert!((row.measured.wait_frac.unwrap() - 0.15).abs() < 1e-15);
        assert!((row.measured.comm_frac.unwrap() - 0.1).abs() < 1e-15, "the communication is unchanged");
        assert!(!row.comm_includes_wait());
        // A rank without it: not measured.
        s.ranks.as_mut().unwrap()[1].exchange.wait_seconds = None;
        row.measured = Measured::of(&s);
        assert_eq!((row.measured.wait_s_per_step, row.measured.wait_frac), (None, None));
    }
}
