//! One run from checked options to its summary: check everything that can be checked before
//! building the model ([`Plan`]), reserve the outputs, build the pinned pool and the
//! simulation, step it until the end time or step limit ([`step_loop`]), then build, write
//! and print the summary.

use crate::cli::GridArg;
use crate::human::print_human;
use crate::output::Outputs;
use crate::progress::Progress;
use crate::ranks::Ranks;
use crate::scenario::{Prepared, ScenarioRun};
use anyhow::{bail, Context, Result};
use mpm_cli::pinning::{self, PinnedPool};
use mpm_cli::summary::{EndReason, HistoryPoint, HistoryRecorder, RunContext, Summary, Timing};
use mpm_core::scenario::impact::{self, CloudFigures, History, ImpactGeometry, DEFAULT_HISTORY_INTERVAL};
use mpm_core::scenario::plate::{PlateGeometry, PlateResult, ShockTracker};
use mpm_core::scenario::taylor::{self, TaylorFigures};
use mpm_core::{Collectives, GridMode, SimConfig, Simulation, Strategy};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::Instant;

/// Raised when the user interrupts the run.
#[derive(Debug, thiserror::Error)]
#[error("interrupted at step {0} (Ctrl-C); no summary written")]
pub struct Interrupted(u64);

/// What the options ask for, checked before anything is built.
struct Plan {
    strategy: Strategy,
    threads: usize,
    /// CPU of each worker, when pinned.
    cpus: Option<Vec<usize>>,
    step_limit: Option<u64>,
    end_time: Option<f64>,
    available_cores: usize,
    /// More workers than cores, or than distinct pinned CPUs.
    oversubscribed: bool,
}

impl Plan {
    /// Check the strategy against the thread count, the CPU list, the end time and the
    /// warm-up; warn (once) when the run is oversubscribed.
    fn check(scenario: &ScenarioRun) -> Result<Self> {
        let o = scenario.options();
        let strategy = o.strategy;
        let threads = o.threads.unwrap_or(1);
        strategy.check_threads(threads).map_err(anyhow::Error::msg)?;
        let cpus = match &o.cpus {
            Some(list) => {
                let c = pinning::parse_cpu_list(list).context("invalid --cpus")?;
                pinning::validate_cpus(&c, threads).context("invalid --cpus")?;
                Some(c)
            }
            None => None,
        };
        let step_limit = o.steps;
        let end_time = match (o.end_time, step_limit) {
            (Some(t), _) => Some(t),
            (None, None) => Some(scenario.default_end_time()?),
            (None, Some(_)) => None,
        };
        if let (Some(w), Some(n)) = (o.warmup, step_limit) {
            if n > 0 && w >= n {
                bail!(
                    "--warmup {w} leaves no steady-state steps of --steps {n}: use fewer warm-up steps (e.g. --warmup {})",
                    n / 10
                );
            }
        }
        let available_cores = pinning::available_cores();
        let distinct_cpus = cpus.as_ref().map(|c| {
            let mut d = c.clone();
            d.sort_unstable();
            d.dedup();
            d.len()
        });
        let oversubscribed = threads > available_cores || distinct_cpus.is_some_and(|d| d < threads);
        if oversubscribed {
            warn_oversubscribed(threads, available_cores, distinct_cpus);
        }
        Ok(Self { strategy, threads, cpus, step_limit, end_time, available_cores, oversubscribed })
    }

    /// Warm-up steps when `--warmup` is not given: a tenth of the expected steps, at most 5.
    fn default_warmup(&self, sim: &Simulation) -> u64 {
        let expected = match (self.step_limit, self.end_time) {
            (Some(n), None) => n,
            (Some(n), Some(t)) => n.min((t / sim.dt_first()).ceil() as u64),
            (None, Some(t)) => (t / sim.dt_first()).ceil() as u64,
            (None, None) => 0,
        };
        (expected / 10).min(5)
    }

    /// Why to stop before the next step, if it is time. The end time counts as reached
    /// when less than a millionth of the first step remains (round-off).
    fn reached(&self, sim: &Simulation) -> Option<EndReason> {
        if let Some(end) = self.end_time {
            if end - sim.time() <= 1e-6 * sim.dt_first() {
                return Some(EndReason::EndTime);
            }
        }
        self.step_limit.is_some_and(|n| sim.steps() >= n).then_some(EndReason::StepLimit)
    }
}

/// The oversubscription warning: timings of this run do not show parallel scaling.
fn warn_oversubscribed(threads: usize, available_cores: usize, distinct_cpus: Option<usize>) {
    match distinct_cpus {
        Some(d) if d < threads && threads <= available_cores => eprintln!(
            "warning: oversubscribed: {threads} threads on {d} pinned CPU(s); timings of this run do not show parallel scaling"
        ),
        _ => eprintln!(
            "warning: oversubscribed: {threads} threads on {available_cores} cores; timings of this run do not show parallel scaling"
        ),
    }
}

/// The pool of the run, pinned as planned; a worker not where it was asked to be is a
/// warning (and the summary says `pinning_verified = false`).
fn start_pool(plan: &Plan) -> Result<PinnedPool> {
    let pool = pinning::build_pool(plan.threads, plan.cpus.as_deref())?;
    let mismatches = pool.mismatches();
    if !mismatches.is_empty() {
        eprintln!(
            "warning: pinning not as requested (the run is marked pinning_verified = false): {}",
            mismatches.join("; ")
        );
    }
    Ok(pool)
}

/// The simulation of a built scenario with the planned strategy, threads, grid and CFL.
fn simulation(
    scenario: &ScenarioRun,
    plan: &Plan,
    setup: mpm_core::Setup,
    exchange: Option<Box<dyn mpm_core::Exchange>>,
) -> Result<Simulation> {
    let o = scenario.options();
    let config = SimConfig {
        strategy: plan.strategy,
        threads: plan.threads,
        grid_mode: match o.grid {
            Some(GridArg::Fixed) => GridMode::Fixed,
            Some(GridArg::Adaptive) => GridMode::Adaptive,
            Some(GridArg::Sparse) => GridMode::Sparse,
            None => scenario.default_grid(exchange.as_ref().is_some_and(|e| e.ranks() > 1)),
        },
        cfl: scenario.cfl(),
        bulk_viscosity: o.q,
        energy_rise_limit: o.energy_rise_limit,
        ..SimConfig::default()
    };
    match exchange {
        Some(exchange) => Simulation::with_exchange(setup, config, exchange),
        None => Simulation::new(setup, config),
    }
    .context("cannot set up the simulation")
}

/// With several ranks and no --cpus: pin this rank's workers inside the CPUs the launcher
/// gave it ([`Ranks::rank_cpus`]); returns whether ranks share CPUs (flagged).
fn place_rank(plan: &mut Plan, ranks: &Ranks) -> Result<bool> {
    if ranks.size() == 1 || plan.cpus.is_some() {
        return Ok(false);
    }
    let (cpus, shared) = ranks.rank_cpus(plan.threads)?;
    if shared {
        eprintln!(
            "warning: oversubscribed: rank {} shares CPUs {cpus:?} with other ranks; timings of this run do not show parallel scaling",
            ranks.rank()
        );
        plan.oversubscribed = true;
    }
    plan.cpus = Some(cpus);
    Ok(shared)
}

/// This rank's line of the summary's `ranks` section.
fn rank_report(
    sim: &Simulation,
    pool: &PinnedPool,
    ranks: &Ranks,
    oversubscribed: bool,
) -> mpm_cli::summary::RankReport {
    mpm_cli::summary::RankReport {
        rank: ranks.rank(),
        cpus: pool.observed_cpus(),
        oversubscribed,
        particles: sim.particles().len(),
        migrated: sim.migrated(),
        busy_s: sim.worker_busy().map_or(0.0, |b| b.iter().sum()),
        steps: sim.steps(),
        exchange: sim.exchange().stats(),
        peak_rss_bytes: mpm_cli::summary::peak_rss_bytes(),
    }
}

/// Ctrl-C stops the run between steps and writes nothing; a second Ctrl-C ends the process
/// at once.
fn install_interrupt_handler() -> Arc<AtomicBool> {
    let interrupted = Arc::new(AtomicBool::new(false));
    let flag = Arc::clone(&interrupted);
    let _ = ctrlc::set_handler(move || {
        if flag.swap(true, Ordering::SeqCst) {
            std::process::exit(130);
        }
    });
    interrupted
}

/// Add the current state to the energy history.
fn record(history: &mut HistoryRecorder, sim: &Simulation) {
    let d = sim.diagnostics();
    history.record(HistoryPoint { step: sim.steps(), time: sim.time(), kinetic: d.kinetic, internal: d.internal });
}

/// What a run measures while it steps besides the energy history: the impact's cloud
/// history, the plate's shock front. Over several ranks every rank tracks them, since the
/// measurements are collective (rank 0 holds the cloud history's samples).
struct Tracking {
    cloud: Option<(History, ImpactGeometry)>,
    shock: Option<ShockTracker>,
}

impl Tracking {
    fn new(impact: Option<ImpactGeometry>, plate: Option<PlateGeometry>) -> Result<Self> {
        let cloud = match impact {
            Some(g) => Some((History::new(DEFAULT_HISTORY_INTERVAL)?, g)),
            None => None,
        };
        Ok(Self { cloud, shock: plate.map(ShockTracker::new) })
    }

    /// Sample the current state (the history only when a new interval has begun).
    fn observe(&mut self, sim: &Simulation, ranks: &mut dyn Collectives) -> Result<()> {
        if let Some((h, g)) = &mut self.cloud {
            h.observe(sim, g, ranks)?;
        }
        if let Some(t) = &mut self.shock {
            t.observe(sim, ranks)?;
        }
        Ok(())
    }

    /// The last history sample at the final state, from its `figures`.
    fn finish(&mut self, sim: &Simulation, figures: &FinalFigures) {
        if let Some((h, _)) = &mut self.cloud {
            h.finish(sim, figures.cloud.as_ref(), figures.failed);
        }
    }
}

/// The scenario's figures of the final state, measured over every rank's particles:
/// collective (every rank calls it), without gathering the particles themselves.
struct FinalFigures {
    /// Failed particles.
    failed: usize,
    taylor: Option<TaylorFigures>,
    /// The debris cloud (rank 0 only).
    cloud: Option<CloudFigures>,
    plate: Option<PlateResult>,
}

/// The Taylor bar's figures of `sim` now (collective), when the run is a bar (`taylor`).
fn bar_figures(taylor: bool, sim: &Simulation, ranks: &mut dyn Collectives) -> Result<Option<TaylorFigures>> {
    Ok(taylor.then(|| taylor::measure_over(sim.particles(), sim.spacing(), ranks)).transpose()?)
}

impl FinalFigures {
    fn measure(sim: &Simulation, taylor: bool, tracking: &Tracking, ranks: &mut dyn Collectives) -> Result<Self> {
        let failed = ranks.total(sim.particles().failed_count())?;
        let taylor = bar_figures(taylor, sim, ranks)?;
        let cloud = match &tracking.cloud {
            Some((_, g)) => impact::measure_over(sim.particles(), |p| sim.exchange().global_id(p), g, ranks)?,
            None => None,
        };
        let plate = match &tracking.shock {
            Some(t) => t.result(sim, ranks)?,
            None => None,
        };
        Ok(Self { failed, taylor, cloud, plate })
    }
}

/// Mark the end of the warm-up: the loop's wall time so far (output excluded), the stage
/// timers and the workers' busy counters.
fn mark_warmup(timing: &mut Timing, sim: &Simulation, wall_s: f64) {
    timing.warmup_wall_s = wall_s;
    timing.warmup_times = *sim.times();
    timing.warmup_busy = sim.worker_busy();
}

/// What the stepping loop reads besides the simulation.
struct LoopContext<'a> {
    plan: &'a Plan,
    pool: &'a PinnedPool,
    warmup: u64,
    interrupted: &'a AtomicBool,
    progress: Option<&'a Progress>,
    geometry: Option<&'a ImpactGeometry>,
    /// The scenario, for the error message of a failed step.
    describe: String,
}

/// Step until the end time or the step limit (or Ctrl-C, or a solver error). The whole
/// loop runs on the pool's first worker (one hand-over to the pool per run, not per step);
/// the solver's parallel phases broadcast from there. Returns why it stopped and the
/// loop's timing (output time excluded). `ranks`: what the tracking measures with.
fn step_loop(
    ctx: &LoopContext<'_>,
    sim: &mut Simulation,
    outputs: &mut Outputs,
    history: &mut HistoryRecorder,
    tracking: &mut Tracking,
    ranks: &mut dyn Collectives,
) -> Result<(EndReason, Timing)> {
    let mut timing = Timing { warmup_steps: ctx.warmup, ..Timing::default() };
    let mut warm_done = ctx.warmup == 0;
    let loop_start = Instant::now();
    let end_reason = ctx.pool.pool.install(|| -> Result<EndReason> {
        loop {
            if let Some(reason) = ctx.plan.reached(sim) {
                return Ok(reason);
            }
            if ctx.interrupted.load(Ordering::Relaxed) {
                ctx.progress.inspect(|p| p.bar.abandon());
                return Err(Interrupted(sim.steps()).into());
            }
            let dt_max = ctx.plan.end_time.map_or(f64::INFINITY, |end| end - sim.time());
            if let Err(e) = sim.step(&ctx.pool.pool, dt_max) {
                ctx.progress.inspect(|p| p.bar.abandon());
                return Err(anyhow::Error::new(e).context(format!(
                    "the simulation failed in the step starting at t = {:.6e} s ({}, strategy {}, {} thread(s)); no summary written",
                    sim.time(),
                    ctx.describe,
                    ctx.plan.strategy.name(),
                    ctx.plan.threads
                )));
            }
            record(history, sim);
            let t0 = Instant::now();
            tracking.observe(sim, ranks)?;
            outputs.spent += t0.elapsed();
            if !warm_done && sim.steps() >= ctx.warmup {
                warm_done = true;
                mark_warmup(&mut timing, sim, loop_start.elapsed().saturating_sub(outputs.spent).as_secs_f64());
            }
            ctx.progress.inspect(|p| p.update(sim));
            outputs.after_step(sim, ctx.geometry)?;
        }
    })?;
    let wall_s = loop_start.elapsed().saturating_sub(outputs.spent).as_secs_f64();
    timing.wall_s = wall_s;
    if !warm_done {
        // The run ended inside the warm-up: no steady-state steps.
        mark_warmup(&mut timing, sim, wall_s);
    }
    Ok((end_reason, timing))
}

/// `mpm run <scenario> ...`: the whole run.
pub fn run_scenario(scenario: &ScenarioRun, command_line: Vec<String>) -> Result<()> {
    let started_unix_s =
        std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map_or(0.0, |d| d.as_secs_f64());
    let o = scenario.options();
    let mut ranks = Ranks::start(o)?;
    let lead = ranks.rank() == 0;
    let mut plan = Plan::check(scenario)?;
    let rank_oversubscribed = place_rank(&mut plan, &ranks)?;
    if ranks.size() > 1 && (o.vtk.is_some() || scenario.radiograph().is_some()) {
        bail!("--vtk and --radiograph are not available over several ranks yet: run them in one process");
    }
    let mut outputs = if lead { Outputs::open(scenario)? } else { Outputs::none() };
    let pool = start_pool(&plan)?;
    let (Prepared { setup, model, velocity, wall, taylor, impact, plate }, exchange) =
        ranks.build(scenario, o.rank_layout, o.split_wait)?;
    let model_name = setup.model.clone();
    let mut sim = simulation(scenario, &plan, setup, exchange)?;
    let (cells, nodes) = (sim.global_geom().num_cells(), sim.global_geom().num_nodes());
    let warmup = o.warmup.unwrap_or_else(|| plan.default_warmup(&sim));
    let interrupted = install_interrupt_handler();

    let mut history = HistoryRecorder::new();
    record(&mut history, &sim);
    let initial_taylor = bar_figures(taylor, &sim, ranks.collectives())?;
    let mut tracking = Tracking::new(impact, plate)?;
    tracking.observe(&sim, ranks.collectives())?;
    outputs.initial(&sim)?;
    let progress = Progress::new(o.quiet || !lead, plan.end_time, plan.step_limit);
    let ctx = LoopContext {
        plan: &plan,
        pool: &pool,
        warmup,
        interrupted: &interrupted,
        progress: progress.as_ref(),
        geometry: impact.as_ref(),
        describe: scenario.describe(),
    };
    let (end_reason, mut timing) =
        step_loop(&ctx, &mut sim, &mut outputs, &mut history, &mut tracking, ranks.collectives())?;
    // The final figures, measured once: the summary's, and the history's last sample.
    let figures = FinalFigures::measure(&sim, taylor, &tracking, ranks.collectives())?;
    tracking.finish(&sim, &figures);
    outputs.finish(&sim, impact.as_ref(), o.quiet)?;
    let cloud_history = tracking.cloud.map(|(h, _)| h);
    if let Some(h) = &cloud_history {
        outputs.history_plot(h, o.quiet)?;
    }
    timing.output_s = outputs.spent.as_secs_f64();
    if let Some(p) = &progress {
        p.bar.finish_and_clear();
    }

    // Rank 0's summary, built before a state dump can release the grid's arrays.
    let summary = lead.then(|| {
        Summary::build(
            &sim,
            RunContext {
                scenario: scenario.name(),
                model,
                model_name,
                velocity,
                wall,
                cells,
                nodes,
                end_time: plan.end_time,
                step_limit: plan.step_limit,
                end_reason,
                timing: &timing,
                pool: &pool,
                available_cores: plan.available_cores,
                oversubscribed: plan.oversubscribed,
                history: history.finish(200),
                failed_particles: figures.failed,
                taylor: initial_taylor.zip(figures.taylor),
                cloud: figures.cloud,
                cloud_history,
                plate: plate.map(|g| (g, figures.plate)),
                command_line,
                started_unix_s,
            },
        )
    });
    if let Some(path) = &o.dump_state {
        ranks.dump_state(&mut sim, path)?;
    }
    // Every rank's peak memory, read after the last thing the run holds memory for.
    let reports = match ranks.size() {
        1 => None,
        _ => ranks.gather_reports(rank_report(&sim, &pool, &ranks, rank_oversubscribed))?,
    };
    let Some(mut summary) = summary else { return Ok(()) };
    summary.ranks = reports;
    summary.peak_rss_bytes = mpm_cli::summary::peak_rss_bytes();
    outputs.commit_json(&summary)?;
    if !o.quiet {
        print_human(&summary, o.json.as_deref(), outputs.snapshots());
    }
    Ok(())
}
