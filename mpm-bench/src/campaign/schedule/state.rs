//! What every scheduler shares while a campaign runs: the options of a session
//! ([`ExecOptions`]), the folder it appends to and the runs still to do ([`Plan`], with the
//! resume rule of [`choose_folder`]), where finished runs go ([`Books`]: the CSV, the
//! session's counts, the manifest and the progress), and the ids of the runs' attempts.
use super::kind::SchedulerKind;
use crate::campaign::exec::process::remove_stale_temp_files;
use crate::campaign::exec::run::{short_hash, RunContext, RunPlan};
use crate::campaign::exec::solver::{workspace_root, Solver};
use crate::campaign::exec::watch::WatchSettings;
use crate::campaign::plan::matrix::{Campaign, PlannedRun, RunKey};
use crate::campaign::plan::memory::{estimate_run_memory, memory_here, memory_verdict};
use crate::campaign::plan::preset::OptLevel;
use crate::campaign::store::csv::{read_rows, repair_garbage, repair_torn_tail, CsvLog};
use crate::campaign::store::lock::{self, FolderLock};
use crate::campaign::store::manifest::{self, BinaryInfo, Manifest, Session};
use crate::campaign::store::record::{Row, Status, SCHEMA_VERSION};
use crate::machine::fingerprint;
use crate::machine::load::Calibration;
use crate::machine::topology::{format_cpu_list, human_bytes, Machine};
use crate::util::now_rfc3339;
use anyhow::{anyhow, Context, Result};
use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};
use std::collections::{HashMap, HashSet};
use std::path::{Path, PathBuf};
use std::time::Duration;

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
    /// With `dry_run`: also time the calibration runs and print the estimated duration
    /// before the plan (needs the solvers).
    pub estimate: bool,
    /// With `dry_run`: plan as for a machine of this many usable cores (the estimate's
    /// speed-up and the plan's oversubscription); the CPUs listed are still this machine's.
    pub assume_cores: Option<usize>,
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
    pub scheduler: SchedulerKind,
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
            self.dir.join(super::kind::JOBS_FILE).display()
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
        SchedulerKind::Local => campaign_dir(&opts.out_root, machine, campaign),
        SchedulerKind::Slurm(s) => opts.out_root.join(s.folder()).join(&campaign.id),
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
pub struct Plan {
    /// This process's hold on the folder (none for a dry run): no other campaign writes it.
    _lock: Option<FolderLock>,
    /// The campaign folder.
    pub dir: PathBuf,
    /// Its `runs.csv`.
    pub csv_path: PathBuf,
    /// Runs of the campaign, done or not.
    pub planned: usize,
    /// The rows already in `runs.csv`.
    pub existing: Vec<Row>,
    /// The runs still to do, with their position in the seeded order.
    pub todo: Vec<(usize, PlannedRun)>,
}

impl Plan {
    /// Choose the folder ([`choose_folder`]), read its rows (unless `--fresh`) and leave out
    /// the configurations they already hold (all of them, or only the `ok` ones with
    /// `--retry-failed`).
    pub fn of(campaign: &Campaign, machine: &Machine, solvers: &[Solver], opts: &ExecOptions) -> Result<Self> {
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
        let mut existing = if csv_path.is_file() && !opts.fresh { read_rows(&csv_path)? } else { Vec::new() };
        for note in resolve_short_keys(&mut existing, order.iter().map(PlannedRun::key)) {
            eprintln!("note: {note}");
        }
        let done = done_keys(&existing, opts.retry_failed);
        let planned = order.len();
        let todo = order.into_iter().enumerate().filter(|(_, r)| !done.contains(&r.key())).collect();
        Ok(Self { _lock: lock, dir, csv_path, planned, existing, todo })
    }

    /// `--dry-run`: every run to do with its CPUs, memory estimate and the guard's verdict;
    /// on a machine of `assumed` cores (not this one) without CPUs, oversubscribed when its
    /// workers are more than those cores.
    pub fn print(&self, campaign: &Campaign, machine: &Machine, assumed: Option<usize>) -> Result<()> {
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
        if let Some(cores) = assumed {
            writeln!(out, "planned for a machine of {cores} usable core(s), not this one: no CPUs listed")?;
        }
        let here = memory_here();
        for (i, r) in &self.todo {
            let pl = RunPlan::of(machine, r)?;
            let (cpus, oversubscribed) = match assumed {
                Some(cores) => ("-".to_string(), r.total_threads() > cores),
                None if pl.requested().is_empty() => ("-".to_string(), pl.oversubscribed),
                None => (format_cpu_list(pl.requested()), pl.oversubscribed),
            };
            let est = estimate_run_memory(&r.spec);
            let verdict = memory_verdict(est, here.as_ref(), campaign.mem_limit);
            writeln!(
                out,
                "{:>4}  {:<48} {:<12} cpus {:<16} mem {:>9}{}{}",
                i,
                r.describe(),
                r.budget_label(),
                cpus,
                human_bytes(est),
                if oversubscribed { "  oversubscribed" } else { "" },
                verdict.map(|v| format!("  SKIP ({v})")).unwrap_or_default()
            )?;
        }
        Ok(())
    }

    /// Create the folder (moving an old `runs.csv` aside with `--fresh`) and open the CSV
    /// log and the folder of JSON summaries.
    pub fn open_folder(&self, fresh: bool, here: bool) -> Result<(CsvLog, PathBuf)> {
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
    pub fn notes(&self, campaign: &Campaign, machine: &Machine, here: bool) {
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
pub struct ManifestLog {
    path: PathBuf,
    manifest: Manifest,
}

impl ManifestLog {
    /// Read (or start) the manifest and append this session (its machine, software,
    /// binaries and planned counts); nothing already recorded is changed. A new campaign
    /// also gets this host's `topology.xml`.
    pub fn start(
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
    pub fn git(&self) -> manifest::GitInfo {
        self.manifest.sessions.last().map(|s| s.git.clone()).unwrap_or_default()
    }

    /// Add the machine of fingerprint `fp` to the manifest's nodes (from
    /// `nodes/<fp>.json`, written by the node that ran a job) when it is not there yet.
    pub fn add_node(&mut self, fp: &str) -> Result<()> {
        if fp.is_empty() || self.manifest.nodes.contains_key(fp) {
            return Ok(());
        }
        let dir = self.path.parent().unwrap_or(Path::new("."));
        let Some(node) = super::job::read_node(dir, fp)? else { return Ok(()) };
        self.manifest.nodes.insert(fp.to_string(), node);
        manifest::write(&self.path, &self.manifest)
    }

    /// Record the session's end and counts.
    pub fn finish(&mut self, counts: manifest::SessionCounts) -> Result<()> {
        if let Some(s) = self.manifest.sessions.last_mut() {
            s.finished = now_rfc3339();
            s.counts = counts;
        }
        manifest::write(&self.path, &self.manifest)
    }
}

/// The progress bar over the runs to do (its ETA weighted by [`cost`]) and a line per run.
pub struct CampaignProgress {
    bar: ProgressBar,
    show: bool,
    total: usize,
    /// The scheduler's queue as last shown: pending, running, done.
    queue: std::cell::Cell<Option<(usize, usize, usize)>>,
}

impl CampaignProgress {
    /// The bar over `todo` (shown when `show`).
    pub fn new(todo: &[(usize, PlannedRun)], show: bool) -> Self {
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

    /// The session is over: the bar goes.
    pub fn finish(&self) {
        self.bar.finish_and_clear();
    }

    /// Run `n` (0-based) starts.
    pub fn start(&self, n: usize, spec: &PlannedRun) {
        self.bar.set_prefix(format!("run {}/{} ({} left)", n + 1, self.total, self.total - n));
        self.bar.set_message(spec.describe());
    }

    /// Under a scheduler: how many runs wait in its queue, run, and are done (without a
    /// terminal, a line whenever that changes).
    pub fn queue(&self, pending: usize, running: usize, done: usize, last: &str) {
        let text = format!("slurm: {pending} pending, {running} running, {done}/{} done", self.total);
        if self.queue.replace(Some((pending, running, done))) != Some((pending, running, done)) && self.bar.is_hidden()
        {
            self.say(&text);
        }
        self.bar.set_prefix(text);
        self.bar.set_message(last.to_string());
    }

    /// Print a line above the bar (or on stderr when it is hidden).
    pub fn say(&self, line: &str) {
        if self.show && self.bar.is_hidden() {
            eprintln!("{line}");
        } else if self.show {
            self.bar.println(line);
        }
    }

    /// Run `n` ended with `row`: its line, and the bar moves on.
    pub fn ended(&self, n: usize, spec: &PlannedRun, row: &Row) {
        if self.show {
            let line =
                format!(
                    "[{}/{}] {} : {}{}",
                    n + 1,
                    self.total,
                    spec.describe(),
                    row.outcome.status.as_str(),
                    match (row.outcome.status, row.measured.as_ref().map(|f| f.timing.wall_s)) {
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

/// What a scheduler works on: what every run shares ([`RunContext`]), the session's plan,
/// the solver of each optimisation level, the attempts of each run so far (for the runs'
/// ids) and where finished runs go ([`Books`]).
pub struct CampaignState<'a> {
    /// What every run of the session shares.
    pub ctx: RunContext<'a>,
    /// The folder and the runs still to do.
    pub plan: &'a Plan,
    /// The solver binary of each optimisation level.
    pub solvers: HashMap<OptLevel, &'a Solver>,
    /// Attempts of each run so far (the rows already there count).
    pub attempts: HashMap<RunKey, usize>,
    /// Where finished runs go.
    pub books: Books<'a>,
}

impl<'a> CampaignState<'a> {
    /// The state of a session about to run `plan`'s runs still to do.
    pub fn new(ctx: RunContext<'a>, plan: &'a Plan, solvers: &'a [Solver], books: Books<'a>) -> Self {
        let mut attempts: HashMap<RunKey, usize> = HashMap::new();
        for r in &plan.existing {
            *attempts.entry(r.key()).or_default() += 1;
        }
        let solvers = solvers.iter().map(|s| (s.opt, s)).collect();
        Self { ctx, plan, solvers, attempts, books }
    }
}

/// Where finished runs go: the CSV, the session's counts, the manifest (the nodes' machines)
/// and the progress bar.
pub struct Books<'a> {
    /// The CSV log.
    pub log: &'a mut CsvLog,
    /// The session's counts.
    pub counts: &'a mut manifest::SessionCounts,
    /// The manifest.
    pub manifest: &'a mut ManifestLog,
    /// The progress bar and the runs' lines.
    pub progress: &'a CampaignProgress,
}

impl Books<'_> {
    /// Append `row`, the `n`-th (0-based) run of this invocation to end, count it, add its
    /// machine to the manifest when new, and print its line.
    pub fn record(&mut self, n: usize, spec: &PlannedRun, row: &Row) -> Result<()> {
        self.log.append(row)?;
        count(self.counts, row);
        self.manifest.add_node(&row.id.machine_id)?;
        self.progress.ended(n, spec, row);
        Ok(())
    }
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

/// The solver binary of `run`'s optimisation level.
pub fn solver_for<'s>(solvers: &HashMap<OptLevel, &'s Solver>, run: &PlannedRun) -> Result<&'s Solver> {
    solvers.get(&run.opt).copied().ok_or_else(|| anyhow!("no solver binary for optimisation level {}", run.opt))
}

/// The id of `run`'s next attempt (`<label>-<key>-a<attempt>`), counting it.
pub fn next_run_id(attempts: &mut HashMap<RunKey, usize>, run: &PlannedRun) -> String {
    let key = run.key();
    let attempt = attempts.entry(key.clone()).or_default();
    let id = format!("{}-{}-a{}", run.label(), key.0, *attempt);
    *attempt += 1;
    id
}

/// Give rows of an older campaign, whose keys have the short form ([`RunKey::names`]), the
/// full key of the planned run they name, in memory (`runs.csv` is not rewritten): such a row
/// counts as that run's. A short key that names several planned runs (their hashes share 16
/// digits) names none of them: its row counts for no run, and those runs run (again). Returns
/// what to say about such keys.
pub fn resolve_short_keys(rows: &mut [Row], planned: impl IntoIterator<Item = RunKey>) -> Vec<String> {
    if !rows.iter().any(|r| r.key().is_short()) {
        return Vec::new();
    }
    let mut by_short: HashMap<RunKey, Vec<RunKey>> = HashMap::new();
    for key in planned {
        let keys = by_short.entry(key.short()).or_default();
        if !keys.contains(&key) {
            keys.push(key);
        }
    }
    let mut notes = Vec::new();
    for row in rows.iter_mut().filter(|r| r.key().is_short()) {
        match by_short.get(&row.key()).map(Vec::as_slice) {
            Some([one]) => row.id.run_key = one.0.clone(),
            Some(several) => {
                let note = format!(
                    "the short run key {} of older rows names {} planned runs; those rows count for none of them, \
                     which run again",
                    row.id.run_key,
                    several.len()
                );
                if !notes.contains(&note) {
                    notes.push(note);
                }
            }
            None => {}
        }
    }
    notes
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

#[cfg(test)]
mod tests {
    use super::*;
    use mpm_core::Strategy;

    fn row(threads: usize, key: impl Fn(&RunKey) -> RunKey) -> Row {
        let mut r = Row::planned(PlannedRun::taylor(1, Strategy::DomainDecomposition, OptLevel::O3, threads, 10));
        r.id.run_key = key(&r.key()).0;
        r.outcome.status = Status::Ok;
        r
    }

    /// Rows of an older campaign (16-digit keys) count as the planned runs they name; new rows
    /// and rows of runs not planned are left as they are; a short key that names two planned
    /// runs counts for neither, and says so once.
    #[test]
    fn short_keys_of_older_rows_count_as_their_runs() {
        let planned: Vec<RunKey> = [1, 2].map(|t| row(t, RunKey::clone).key()).to_vec();
        let mut rows = vec![row(1, RunKey::short), row(2, RunKey::clone), row(4, RunKey::short)];
        assert!(resolve_short_keys(&mut rows, planned.clone()).is_empty());
        assert_eq!(rows[0].key(), planned[0], "the short key now reads as its run's");
        assert_eq!(rows[1].key(), planned[1]);
        assert!(rows[2].key().is_short(), "not a planned run: left alone");
        let done = done_keys(&rows, false);
        assert!(planned.iter().all(|k| done.contains(k)));
        // Two planned keys of one short form (a collision of 16 digits, made up here).
        let short = planned[0].short();
        let twin = RunKey(format!("{}{}-r0", &short.0[..16], "0".repeat(48)));
        let mut rows = vec![row(1, RunKey::short), row(1, RunKey::short)];
        let notes = resolve_short_keys(&mut rows, [planned[0].clone(), twin.clone()]);
        assert_eq!(notes.len(), 1, "{notes:?}");
        assert!(notes[0].contains("names 2 planned runs"), "{notes:?}");
        let done = done_keys(&rows, false);
        assert!(!done.contains(&planned[0]) && !done.contains(&twin), "neither run is done");
    }
}
