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
    let mut counts = manifest::SessionCounts {
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
    if here && plan.todo.iter().any(|(_, run)| run.spec.ranks > 1) {
        if let Some(why) = runner.launcher_refusal(&campaign.launcher) {
            bail!("{why}");
        }
    }
    let (mut log, json_dir) = plan.open_folder(opts.fresh, here)?;
    // Under a scheduler each job watches its own node.
    let watch = opts.watch.filter(|_| here).map(|w| HostWatch::start(w, machine.usable_pus().len()));
    let calibration = watch.as_ref().map(HostWatch::calibration);
    let mut manifest = ManifestLog::start(campaign, machine, solvers, opts, &plan.dir, counts, calibration)?;
    if opts.eta && here {
        match estimate_duration(runner, solvers, &plan.todo, &json_dir, machine.usable_pus().len()) {
            Ok(eta) => eprintln!("{eta}"),
            Err(e) => eprintln!("note: no duration estimate: {e:#}"),
        }
    }
    let progress = CampaignProgress::new(&plan.todo, !opts.quiet);
    let checkpoint_root = plan.dir.join("checkpoints");
    let ctx = RunContext { campaign, machine, git: manifest.git(), json_dir, checkpoint_root, interrupted };
    let books = Books { log: &mut log, counts: &mut counts, manifest: &mut manifest, progress: &progress };
    let mut state = CampaignState::new(ctx, &plan, solvers, books);
    let mut scheduler: Box<dyn Scheduler + '_> = match &opts.scheduler {
        SchedulerKind::Slurm(options) => Box::new(Slurm { options, watch: opts.watch }),
        SchedulerKind::Local => Box::new(Local { runner, watch }),
    };
    scheduler.run_all(&mut state)?;
    drop(state);
    progress.finish();
    counts.interrupted |= interrupted.load(Ordering::SeqCst);
    let wall = t0.elapsed();
    manifest.finish(counts)?;
    debug_assert_eq!(log.path(), plan.csv_path.as_path());
    Ok(ExecSummary { dir: plan.dir, counts, wall })
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
