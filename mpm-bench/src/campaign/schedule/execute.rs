//! `mpm-bench run`'s campaign: plan the session ([`super::state::Plan`]), open the folder,
//! its manifest and progress, and hand the runs still to do to the scheduler chosen
//! ([`super::local::Local`] or [`super::slurm::Slurm`], both a [`super::Scheduler`]).
use super::kind::SchedulerKind;
use super::local::Local;
use super::scheduler::Scheduler;
use super::slurm::Slurm;
use super::state::{Books, CampaignProgress, CampaignState, ExecOptions, ExecSummary, ManifestLog, Plan};
use crate::campaign::exec::estimate::{estimate_duration, nominal_estimate};
use crate::campaign::exec::process::Runner;
use crate::campaign::exec::run::RunContext;
use crate::campaign::exec::solver::Solver;
use crate::campaign::exec::watch::HostWatch;
use crate::campaign::plan::matrix::Campaign;
use crate::campaign::store::csv::CsvLog;
use crate::campaign::store::manifest::{self};
use crate::machine::topology::Machine;
use anyhow::{bail, Context, Result};
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Instant;

/// Run (or resume) `campaign` on `machine` with `runner` (here) or as Slurm jobs, appending a
/// row after every run.
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
    let counts = manifest::SessionCounts {
        planned: plan.planned,
        already_done: plan.planned - plan.todo.len(),
        ..Default::default()
    };
    if opts.dry_run {
        plan.print(campaign, machine, opts.assume_cores)?;
        let cores = opts.assume_cores.unwrap_or_else(|| machine.usable_pus().len());
        if opts.estimate {
            println!("{}", dry_run_estimate(runner, solvers, &plan.todo, cores)?);
        } else {
            println!("{}", nominal_estimate(&plan.todo, cores));
        }
        return Ok(ExecSummary { dir: plan.dir, counts, wall: t0.elapsed() });
    }
    let here = opts.scheduler.runs_here();
    plan.notes(campaign, machine, here);
    if plan.todo.is_empty() {
        // Nothing to do: the folder, its manifest and topology stay as they are.
        return Ok(ExecSummary { dir: plan.dir, counts, wall: t0.elapsed() });
    }
    // Under Slurm too: the jobs start the same launcher as the same user.
    if plan.todo.iter().any(|(_, run)| run.spec.ranks > 1) {
        if let Some(why) = runner.launcher_refusal(&campaign.launcher) {
            bail!("{why}");
        }
    }
    // Under a scheduler each job watches its own node.
    let watch = opts.watch.filter(|_| here).map(|w| HostWatch::start(w, machine.usable_pus().len()));
    let eta = (opts.eta && here).then_some(&mut *runner);
    let mut session = Session::open(plan, (campaign, machine, solvers), opts, counts, watch.as_ref(), eta)?;
    let mut state = session.state(campaign, machine, solvers, interrupted);
    let mut scheduler: Box<dyn Scheduler + '_> = match &opts.scheduler {
        SchedulerKind::Slurm(options) => Box::new(Slurm { options, watch: opts.watch }),
        SchedulerKind::Local => Box::new(Local { runner, watch }),
    };
    scheduler.run_all(&mut state)?;
    drop(state);
    let dir = session.plan.dir.clone();
    let counts = session.close(interrupted)?;
    Ok(ExecSummary { dir, counts, wall: t0.elapsed() })
}

/// A session's campaign folder open for appending (what a scheduler's runs are recorded
/// in): the plan, the CSV log, the folder of the runs' files, the manifest with this
/// session, its counts and the progress bar. `mpm-bench run` opens one
/// ([`execute`]); `mpm-bench ab` two, one per build.
pub struct Session {
    /// The folder and the runs still to do.
    pub plan: Plan,
    /// The CSV log.
    pub log: CsvLog,
    /// The folder of the runs' summaries and spec files.
    pub json_dir: std::path::PathBuf,
    /// The manifest with this session appended.
    pub manifest: ManifestLog,
    /// The session's counts so far.
    pub counts: manifest::SessionCounts,
    /// The progress bar and the runs' lines.
    pub progress: CampaignProgress,
}

impl Session {
    /// Create the folder, open its CSV and append this session to its manifest (with the
    /// host watch's calibration when the host is watched); with `eta`, time a short run per
    /// optimisation level and print the session's estimated duration before the progress
    /// bar starts.
    pub fn open(
        plan: Plan,
        (campaign, machine, solvers): (&Campaign, &Machine, &[Solver]),
        opts: &ExecOptions,
        counts: manifest::SessionCounts,
        watch: Option<&HostWatch>,
        eta: Option<&mut (dyn Runner + '_)>,
    ) -> Result<Self> {
        let here = opts.scheduler.runs_here();
        let (log, json_dir) = plan.open_folder(opts.fresh, here)?;
        let calibration = watch.map(HostWatch::calibration);
        let manifest = ManifestLog::start(campaign, machine, solvers, opts, &plan.dir, counts, calibration)?;
        if let Some(runner) = eta {
            match estimate_duration(runner, solvers, &plan.todo, &json_dir, machine.usable_pus().len()) {
                Ok(eta) => eprintln!("{eta}"),
                Err(e) => eprintln!("note: no duration estimate: {e:#}"),
            }
        }
        let progress = CampaignProgress::new(&plan.todo, !opts.quiet);
        Ok(Self { plan, log, json_dir, manifest, counts, progress })
    }

    /// The state a scheduler works on: every run of the session with its books.
    pub fn state<'a>(
        &'a mut self,
        campaign: &'a Campaign,
        machine: &'a Machine,
        solvers: &'a [Solver],
        interrupted: &'a AtomicBool,
    ) -> CampaignState<'a> {
        let ctx = RunContext {
            campaign,
            machine,
            git: self.manifest.git(),
            json_dir: self.json_dir.clone(),
            checkpoint_root: self.plan.dir.join("checkpoints"),
            interrupted,
        };
        let books = Books {
            log: &mut self.log,
            counts: &mut self.counts,
            manifest: &mut self.manifest,
            progress: &self.progress,
        };
        CampaignState::new(ctx, &self.plan, solvers, books)
    }

    /// The session is over: the bar goes, the manifest records its end and counts.
    pub fn close(mut self, interrupted: &AtomicBool) -> Result<manifest::SessionCounts> {
        self.progress.finish();
        self.counts.interrupted |= interrupted.load(Ordering::SeqCst);
        self.manifest.finish(self.counts)?;
        debug_assert_eq!(self.log.path(), self.plan.csv_path.as_path());
        Ok(self.counts)
    }
}

/// A dry run's estimate: the calibration runs write into a folder of their own under the
/// system's temporary folder, removed afterwards (a dry run writes nothing into the results).
fn dry_run_estimate(
    runner: &mut dyn Runner,
    solvers: &[Solver],
    todo: &[(usize, crate::campaign::plan::matrix::PlannedRun)],
    cores: usize,
) -> Result<String> {
    let dir = std::env::temp_dir().join(format!("mpm-bench-estimate-{}", std::process::id()));
    std::fs::create_dir_all(&dir).with_context(|| format!("cannot create {}", dir.display()))?;
    let estimate = estimate_duration(runner, solvers, todo, &dir, cores);
    let _ = std::fs::remove_dir_all(&dir);
    estimate
}
