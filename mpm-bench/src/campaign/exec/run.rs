//! One run: placed on this machine ([`RunPlan`]), guarded by the memory estimate, run as a
//! fresh child process by a [`Runner`], and recorded as one row from the planned run, the
//! placement, the summary's figures, the host around it and the outcome
//! ([`RunContext::run_one`], the row assembled in one place, [`RunContext::row`]).
//!
//! * Oversubscription: rows with more workers (ranks x threads per rank) than usable PUs are
//!   flagged. A run whose observed CPUs differ from the requested ones is recorded `invalid`.
//! * Several ranks ([`RunPlan`]): the policy places ranks x threads workers; that CPU set is
//!   the launcher's affinity mask and each rank must be seen on its slice of it.
//! * Checkpoints (a campaign's `checkpoint_every`, [`RunCheckpoints`]): each run saves its
//!   state into `<campaign>/checkpoints/<run>/`; an attempt killed, timed out or interrupted
//!   is continued from there by the next attempt (`mpm resume`), the compute time it lost is
//!   booked, and the run's row records its restarts and the time lost.
use crate::campaign::exec::launcher;
use crate::campaign::exec::process::{RunOutput, RunRequest, Runner};
use crate::campaign::exec::solver::Solver;
use crate::campaign::exec::watch::HostWatch;
use crate::campaign::plan::matrix::{Campaign, PlannedRun};
use crate::campaign::plan::memory::{estimate_run_memory, memory_here, memory_verdict};
use crate::campaign::store::manifest::{self};
use crate::campaign::store::record::{HostColumns, Outcome, Placement, Row, RowId, Status};
use crate::machine::fingerprint;
use crate::machine::load::HostReading;
use crate::machine::placement::PinPolicy;
use crate::machine::topology::Machine;
use crate::util::{node_name, now_rfc3339};
use anyhow::Result;
use mpm_spec::spec::CheckpointOutput;
use mpm_spec::summary::Figures;
use mpm_spec::Summary;
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};

/// What every run of one invocation shares: the campaign, the machine the runs run on, the
/// git state, the folder of the runs' files, that of their checkpoints and the interrupt flag.
pub struct RunContext<'a> {
    /// The campaign.
    pub campaign: &'a Campaign,
    /// The machine the runs run on (this node).
    pub machine: &'a Machine,
    /// The git state of the session.
    pub git: manifest::GitInfo,
    /// The folder of the runs' summaries and spec files.
    pub json_dir: PathBuf,
    /// `<campaign>/checkpoints`: each run's checkpoint folder (with a campaign checkpoint
    /// interval).
    pub checkpoint_root: PathBuf,
    /// Raised by Ctrl-C.
    pub interrupted: &'a AtomicBool,
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
    /// The checkpoints of `run` under `root` (in the folder named with the short form of its
    /// key when an older harness left one there).
    pub fn of(root: &Path, run: &PlannedRun) -> Self {
        let name = format!("{}-{}", run.label(), run.key().0);
        let short = format!("{}-{}", run.label(), run.key().short().0);
        let name = if !root.join(&name).exists() && root.join(&short).is_dir() { short } else { name };
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
    pub fn run_one(
        &self,
        runner: &mut dyn Runner,
        watch: Option<&mut HostWatch>,
        solver: &Solver,
        planned: &PlannedRun,
        order_index: usize,
        run_id: String,
    ) -> Result<Option<Row>> {
        let plan = RunPlan::of(self.machine, planned)?;
        let estimate = estimate_run_memory(&planned.spec);
        let attempt = match memory_verdict(estimate, memory_here().as_ref(), self.campaign.mem_limit) {
            Some(reason) => Attempt::skipped(reason),
            None => match self.attempt(runner, watch, solver, planned, &plan, &run_id)? {
                Some(a) => a,
                None => return Ok(None),
            },
        };
        let id = RowId { order_index, run_id, timestamp: now_rfc3339(), ..self.row_id(solver, planned) };
        Ok(Some(attempt.into_row(id, planned, &plan, estimate, self.machine.usable_pus().len())))
    }

    /// What identifies a row of `run` run here: the campaign, the software, the seed, this
    /// machine and node.
    fn row_id(&self, solver: &Solver, run: &PlannedRun) -> RowId {
        RowId {
            machine_id: fingerprint::fingerprint(self.machine),
            node: node_name(),
            ..planned_row(self.campaign, &self.git, solver, run).id
        }
    }

    /// Run `planned` as `plan` places it, with its checkpoints and the host watched around
    /// it. `None` when the campaign was interrupted during the run.
    fn attempt(
        &self,
        runner: &mut dyn Runner,
        watch: Option<&mut HostWatch>,
        solver: &Solver,
        planned: &PlannedRun,
        plan: &RunPlan,
        run_id: &str,
    ) -> Result<Option<Attempt>> {
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
        let watched = watch.map(|w| {
            let before = w.before_run(&probe_cpus);
            (w, before)
        });
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
        let mut attempt = Attempt::of(&req, &out);
        if let Some(c) = &checkpoints {
            if attempt.status != Status::Ok {
                c.record_loss(started, ended, &attempt.reason)?;
            }
            // What the attempts before this one lost (and this one, if it did not finish).
            attempt.lost_compute_s = Some(c.lost_s());
            if attempt.status == Status::Ok {
                c.remove();
            }
        }
        attempt.host = watched.map(|(w, before)| w.after_run(&probe_cpus, before));
        Ok(Some(attempt))
    }
}

/// What one attempt of a run gave, everything its row records beside the plan: the
/// process's end, the summary's figures and where its workers were seen, the host around
/// it, the checkpoints' lost time; or why it did not run.
#[derive(Debug, Default)]
struct Attempt {
    status: Status,
    reason: String,
    exit_code: Option<i32>,
    process_wall_s: Option<f64>,
    lost_compute_s: Option<f64>,
    /// CPUs each worker was seen on (rank by rank with several ranks).
    observed_cpus: Vec<usize>,
    /// With several ranks: each rank's CPUs.
    rank_cpus: Vec<Vec<usize>>,
    /// The solver found the run oversubscribed.
    oversubscribed: bool,
    measured: Option<Figures>,
    host: Option<HostReading>,
}

impl Attempt {
    /// A run the memory guard did not start.
    fn skipped(reason: String) -> Self {
        Self { status: Status::Skipped, reason, ..Self::default() }
    }

    /// A finished child process: failed when the process failed or left no readable
    /// summary, invalid when the summary contradicts the request (another spec than the one
    /// asked, CPUs not as placed, non-finite figures), ok otherwise.
    fn of(req: &RunRequest, out: &RunOutput) -> Self {
        let mut a = Self { exit_code: out.exit_code, process_wall_s: Some(out.process_wall_s), ..Self::default() };
        if out.exit_code != Some(0) || out.error.is_some() {
            a.status = Status::Failed;
            a.reason = process_failure(out);
            if let Some(hint) = req.launcher.as_ref().and(launcher::failure_hint(&out.stderr_tail)) {
                a.reason = format!("{hint}: {}", a.reason);
            }
            return a;
        }
        let summary = match read_summary(&req.json_path) {
            Ok(s) => s,
            Err(reason) => return Self { status: Status::Failed, reason, ..a },
        };
        let ranks = summary.ranks.as_deref().unwrap_or_default();
        a.observed_cpus = if ranks.is_empty() {
            summary.pinning.observed_cpus.clone()
        } else {
            ranks.iter().flat_map(|r| r.cpus.iter().copied()).collect()
        };
        a.rank_cpus = ranks.iter().map(|r| r.cpus.clone()).collect();
        a.oversubscribed = summary.pinning.oversubscribed || ranks.iter().any(|r| r.oversubscribed);
        let checked = check_spec(&summary, &req.spec).and_then(|()| {
            if req.spec.ranks > 1 {
                check_ranks(&summary, req.spec.ranks, req.spec.threads, req.mask.as_deref().unwrap_or_default())
            } else {
                check_summary(&summary, &req.spec.cpus.clone().unwrap_or_default())
            }
        });
        (a.status, a.reason) = match checked {
            Ok(()) => (Status::Ok, String::new()),
            Err(reason) => (Status::Invalid, reason),
        };
        a.measured = Some(summary.figures);
        a
    }

    /// The row of this attempt of `run` (`id`), placed by `plan` with a memory estimate of
    /// `estimate` bytes on a host of `pus` usable PUs: the one place a run's row is made.
    fn into_row(self, id: RowId, run: &PlannedRun, plan: &RunPlan, estimate: u64, pus: usize) -> Row {
        // A CPU quota below the workers shares their time like too few cores do.
        let workers = run.spec.total_workers() as f64;
        let quota_short = self.measured.as_ref().and_then(|m| m.cpu_quota).is_some_and(|q| q < workers);
        let placement = Placement {
            requested_cpus: plan.requested().to_vec(),
            observed_cpus: self.observed_cpus,
            rank_cpus: self.rank_cpus,
            oversubscribed: plan.oversubscribed || self.oversubscribed || quota_short,
            physical_cores: Some(plan.physical_cores),
        };
        let host = self.host.map(|h| HostColumns::of(&h, run.spec.total_workers(), pus)).unwrap_or_default();
        let outcome = Outcome {
            status: self.status,
            reason: self.reason,
            exit_code: self.exit_code,
            process_wall_s: self.process_wall_s,
            mem_estimate_bytes: estimate,
            lost_compute_s: self.lost_compute_s,
        };
        let mut row = Row { id, run: run.clone(), placement, measured: self.measured, host, outcome };
        row.flag_low_cpu_share();
        row
    }
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
    /// The physical cores the run's workers can use (SMT siblings once): those of its
    /// CPUs when pinned, else the workers up to the machine's cores.
    pub physical_cores: usize,
}

impl RunPlan {
    /// The plan of `run` on `machine`.
    pub fn of(machine: &Machine, run: &PlannedRun) -> Result<Self> {
        let placement = machine.place_ranks(&run.pin, run.spec.ranks, run.spec.threads)?;
        let cpus = (!matches!(run.pin, PinPolicy::None)).then_some(placement.cpus);
        let physical_cores = match &cpus {
            Some(c) => machine.physical_cores_of(c),
            None => run.spec.total_workers().min(machine.num_cores().max(1)),
        };
        Ok(Self { cpus, oversubscribed: placement.oversubscribed, physical_cores })
    }

    /// What the row records as requested: `cpus`, or nothing.
    pub fn requested(&self) -> &[usize] {
        self.cpus.as_deref().unwrap_or_default()
    }
}

/// The first 16 hex digits of a hash, as recorded in every row.
pub fn short_hash(sha256: &str) -> String {
    sha256.chars().take(16).collect()
}

/// The row of `run` before it runs anywhere: its campaign, software and seed.
pub fn planned_row(campaign: &Campaign, git: &manifest::GitInfo, solver: &Solver, run: &PlannedRun) -> Row {
    let mut row = Row::planned(run.clone());
    row.id.campaign_id = campaign.id.clone();
    row.id.git_commit = git.commit.clone();
    row.id.git_dirty = git.dirty;
    row.id.binary_sha256 = short_hash(&solver.sha256);
    row.id.seed = campaign.seed;
    row
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
pub fn read_summary(path: &Path) -> Result<Summary, String> {
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
    if !requested.is_empty() && s.pinning.requested_cpus != requested {
        return Err(format!(
            "solver reports requested CPUs [{}], harness asked for [{}]",
            list(&s.pinning.requested_cpus),
            list(requested)
        ));
    }
    if !requested.is_empty() && s.pinning.observed_cpus != requested {
        return Err(format!(
            "pinning not honoured: requested CPUs [{}], observed [{}]",
            list(requested),
            list(&s.pinning.observed_cpus)
        ));
    }
    if [s.figures.physics.kinetic_energy, s.figures.physics.internal_energy, s.figures.timing.wall_s]
        .iter()
        .any(|x| !x.is_finite())
    {
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
    use crate::campaign::plan::preset::OptLevel;
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

    /// The physical cores a run could use count SMT siblings once; a cgroup CPU quota below
    /// the workers flags the row as time sharing.
    #[test]
    fn physical_cores_and_a_short_cpu_quota() {
        let smt = Machine::synthetic("pack:1 core:2 pu:2").unwrap();
        assert_eq!(smt.physical_cores_of(&[0, 1, 2, 3]), 2);
        assert_eq!(smt.physical_cores_of(&[0, 1]), 1, "PUs 0 and 1 are siblings of core 0");
        let p = RunPlan::of(&smt, &spec(1, 4, PinPolicy::CLOSE)).unwrap();
        assert_eq!((p.physical_cores, p.oversubscribed), (2, false));
        assert_eq!(
            RunPlan::of(&smt, &spec(1, 2, PinPolicy::CLOSE)).unwrap().physical_cores,
            2,
            "one PU per core first"
        );
        assert_eq!(RunPlan::of(&smt, &spec(1, 4, PinPolicy::None)).unwrap().physical_cores, 2);
        assert_eq!(RunPlan::of(&smt, &spec(1, 1, PinPolicy::None)).unwrap().physical_cores, 1);

        let run = spec(1, 2, PinPolicy::CLOSE);
        let plan = RunPlan::of(&smt, &run).unwrap();
        let row = |quota: Option<f64>| {
            let f = Figures { cpu_quota: quota, ..Figures::default() };
            let a = Attempt { status: Status::Ok, measured: Some(f), ..Attempt::default() };
            a.into_row(RowId::default(), &run, &plan, 0, 4)
        };
        assert_eq!(row(None).placement.physical_cores, Some(2));
        assert!(!row(None).placement.oversubscribed);
        assert!(!row(Some(2.0)).placement.oversubscribed);
        assert!(row(Some(1.5)).placement.oversubscribed, "1.5 CPUs of time for 2 workers");
    }

    fn summary(cpus: &[&[usize]]) -> Summary {
        let ranks = cpus
            .iter()
            .enumerate()
            .map(|(rank, c)| RankReport { rank, cpus: c.to_vec(), ..RankReport::default() })
            .collect();
        let mut s = Summary { ranks: Some(ranks), ..Summary::default() };
        s.figures.timing.wall_s = 1.0;
        s
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

    /// The `ranks` section fills the hybrid columns (the figures themselves are computed
    /// with the summary, `mpm_spec::summary::Communication::of`): a run over ranks without
    /// the waiting measured apart has its exchange including the waiting; with
    /// --split-wait it has not.
    #[test]
    fn rank_reports_fill_the_hybrid_columns() {
        let mut s = summary(&[&[0], &[1]]);
        s.figures.progress.steps = 10;
        s.figures.timing.wall_s = 2.0;
        let mut reports = s.ranks.take().unwrap();
        for (i, r) in reports.iter_mut().enumerate() {
            r.exchange.seconds = 0.1 * (i + 1) as f64;
        }
        s.finish(Some(reports.clone()), None, None, None);
        let mut row = Row::planned(spec(2, 1, PinPolicy::CLOSE));
        row.measured = Some(s.figures.clone());
        assert!(row.comm_includes_wait());
        for (i, r) in reports.iter_mut().enumerate() {
            r.exchange.wait_seconds = Some(0.3 - 0.1 * i as f64);
        }
        s.finish(Some(reports), None, None, None);
        row.measured = Some(s.figures.clone());
        assert!((row.measured.as_ref().and_then(|f| f.communication.wait_frac).unwrap() - 0.15).abs() < 1e-15);
        assert!(!row.comm_includes_wait());
    }
}
