//! One run from checked options to its summary: check everything that can be checked before
//! building the model ([`Plan`]), reserve the outputs, build the pinned pool and the
//! simulation, step it until the end time or step limit ([`step_loop`], writing checkpoints
//! when due), then build, write and print the summary ([`go`], which a run continued from
//! a checkpoint enters too).

use crate::checkpointing::{Carried, Checkpointer, RunLog, SavedCloud, SavedSnapshot};
use crate::cli::Control;
use crate::human::print_human;
use crate::output::Outputs;
use crate::progress::Progress;
use crate::ranks::Ranks;
use anyhow::{bail, Context, Result};
use mpm_cli::checkpoint::Folder;
use mpm_cli::pinning::{self, PinnedPool};
use mpm_cli::summary::{self, HistoryRecorder, RunContext, Timing};
use mpm_cli::usage::UsageMeter;
use mpm_core::scenario::impact::{self, CloudFigures, History, ImpactGeometry, DEFAULT_HISTORY_INTERVAL};
use mpm_core::scenario::plate::{PlateGeometry, PlateResult, ShockTracker};
use mpm_core::scenario::taylor::{self, TaylorFigures};
use mpm_core::{Collectives, SimConfig, Simulation};
use mpm_spec::scenario::Prepared;
use mpm_spec::spec::Budget;
use mpm_spec::summary::{CheckpointReport, EndReason, HistoryPoint, RankReport, MIN_CPU_SHARE};
use mpm_spec::RunSpec;
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

/// Raised when the user interrupts the run.
#[derive(Debug, thiserror::Error)]
#[error("interrupted at step {0} (Ctrl-C); no summary written")]
pub struct Interrupted(pub u64);

/// Worker threads per core beyond which a run is refused: more is not a measurement, and
/// `--threads 100000` would only bring the machine to its knees.
pub const MAX_THREADS_PER_CORE: usize = 16;

/// What the machine says about the spec, checked before anything is built.
pub struct Plan {
    available_cores: usize,
    /// More workers than cores, or than distinct pinned CPUs.
    oversubscribed: bool,
}

impl Plan {
    /// Check the spec against this machine: the CPU list, a thread count not far beyond the
    /// cores, the memory estimate against the memory available (unless `force`); warn (once)
    /// when the run is oversubscribed.
    pub fn check(spec: &RunSpec, force: bool) -> Result<Self> {
        let threads = spec.threads;
        if let Some(c) = &spec.cpus {
            pinning::validate_cpus(c, threads).context("invalid --cpus")?;
        }
        let available_cores = pinning::available_cores();
        let limit = MAX_THREADS_PER_CORE * available_cores.max(1);
        if threads > limit {
            bail!(
                "--threads {threads} is more than {MAX_THREADS_PER_CORE} per core of the {available_cores} core(s) \
                 here (at most {limit}): such a run measures nothing but time sharing; use at most {limit}"
            );
        }
        check_memory(spec, force)?;
        let distinct_cpus = spec.cpus.as_ref().map(|c| {
            let mut d = c.clone();
            d.sort_unstable();
            d.dedup();
            d.len()
        });
        let oversubscribed = threads > available_cores || distinct_cpus.is_some_and(|d| d < threads);
        if oversubscribed {
            warn_oversubscribed(threads, available_cores, distinct_cpus);
        }
        Ok(Self { available_cores, oversubscribed })
    }
}

/// Refuse a run whose estimated memory (per rank: its share of the model plus the MPI
/// process's own) exceeds the memory available now, before anything is allocated; `force`
/// tries anyway.
fn check_memory(spec: &RunSpec, force: bool) -> Result<()> {
    let whole = spec.scenario.size().memory_bytes(spec.strategy, spec.threads);
    let estimate = if spec.ranks > 1 { whole / spec.ranks as u64 + RANK_OVERHEAD_BYTES } else { whole };
    let Some(available) = mpm_cli::memory::available_memory() else { return Ok(()) };
    if estimate > available && !force {
        bail!(
            "the run needs about {} ({}, {} with {} thread(s){}) but {} is available: use a smaller model \
             (e.g. a coarser --spacing or larger --cell), fewer threads with ae, or --force to try anyway",
            mpm_cli::memory::human_bytes(estimate),
            spec.scenario.describe(),
            spec.strategy,
            spec.threads,
            if spec.ranks > 1 { format!(", per rank of {}", spec.ranks) } else { String::new() },
            mpm_cli::memory::human_bytes(available)
        );
    }
    Ok(())
}

/// Memory of an MPI rank besides its share of the model: the MPI library, its buffers.
const RANK_OVERHEAD_BYTES: u64 = 64 << 20;

/// Why to stop before the next step, if it is time. The end time counts as reached when
/// less than a millionth of the first step remains (round-off).
fn reached(budget: &Budget, sim: &Simulation) -> Option<EndReason> {
    if let Some(end) = budget.end_time_s {
        if end - sim.time() <= 1e-6 * sim.dt_first() {
            return Some(EndReason::EndTime);
        }
    }
    budget.steps.is_some_and(|n| sim.steps() >= n).then_some(EndReason::StepLimit)
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
pub fn start_pool(threads: usize, cpus: Option<&[usize]>) -> Result<PinnedPool> {
    let pool = pinning::build_pool(threads, cpus)?;
    let mismatches = pool.mismatches();
    if !mismatches.is_empty() {
        eprintln!(
            "warning: pinning not as requested (the run is marked pinning_verified = false): {}",
            mismatches.join("; ")
        );
    }
    Ok(pool)
}

/// The solver settings the spec asks for: strategy, threads, grid, physics, the injected
/// slowdown.
pub fn sim_config(spec: &RunSpec) -> SimConfig {
    SimConfig {
        strategy: spec.strategy,
        threads: spec.threads,
        grid_mode: spec.grid,
        cfl: spec.physics.cfl,
        bulk_viscosity: spec.physics.q,
        energy_rise_limit: spec.physics.energy_rise_limit.as_f64(),
        inject_slowdown: spec.inject_slowdown.unwrap_or(0.0),
        ..SimConfig::default()
    }
}

/// The simulation of a built scenario as the spec asks ([`sim_config`]).
fn simulation(
    spec: &RunSpec,
    setup: mpm_core::Setup,
    exchange: Option<Box<dyn mpm_core::Exchange>>,
) -> Result<Simulation> {
    let config = sim_config(spec);
    match exchange {
        Some(exchange) => Simulation::with_exchange(setup, config, exchange),
        None => Simulation::new(setup, config),
    }
    .context("cannot set up the simulation")
}

/// The CPUs of this process's workers: the spec's, or with several ranks and none given,
/// a slice of the CPUs the launcher gave this rank ([`Ranks::rank_cpus`]); and whether ranks
/// share CPUs (flagged).
pub fn place_rank(spec: &RunSpec, plan: &mut Plan, ranks: &Ranks) -> Result<(Option<Vec<usize>>, bool)> {
    if ranks.size() == 1 || spec.cpus.is_some() {
        return Ok((spec.cpus.clone(), false));
    }
    let (cpus, shared) = ranks.rank_cpus(spec.threads)?;
    if shared {
        eprintln!(
            "warning: oversubscribed: rank {} shares CPUs {cpus:?} with other ranks; timings of this run do not show parallel scaling",
            ranks.rank()
        );
        plan.oversubscribed = true;
    }
    Ok((Some(cpus), shared))
}

/// This rank's line of the summary's `ranks` section.
fn rank_report(sim: &Simulation, pool: &PinnedPool, ranks: &Ranks, oversubscribed: bool) -> RankReport {
    RankReport {
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
pub struct Tracking {
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

    /// The tracking a checkpoint saved, on the scenario's geometries.
    pub fn restored(
        cloud: Option<SavedCloud>,
        shock_path: Option<Vec<[f64; 2]>>,
        impact: Option<ImpactGeometry>,
        plate: Option<PlateGeometry>,
    ) -> Result<Self> {
        let cloud = match (impact, cloud) {
            (Some(g), Some(c)) => Some((History::resumed(c.interval, c.samples, c.last_time)?, g)),
            (None, None) => None,
            _ => bail!("the checkpoint's cloud history does not fit the scenario"),
        };
        let shock = match (plate, shock_path) {
            (Some(geometry), Some(path)) => {
                Some(ShockTracker { geometry, path: path.into_iter().map(|[t, z]| (t, z)).collect() })
            }
            (None, None) => None,
            _ => bail!("the checkpoint's shock tracker does not fit the scenario"),
        };
        Ok(Self { cloud, shock })
    }

    /// What a checkpoint saves of it.
    fn saved(&self) -> (Option<SavedCloud>, Option<Vec<[f64; 2]>>) {
        let cloud = self.cloud.as_ref().map(|(h, _)| SavedCloud {
            interval: h.interval,
            samples: h.samples.clone(),
            last_time: h.last_time(),
        });
        (cloud, self.shock.as_ref().map(|t| t.path.iter().map(|&(t, z)| [t, z]).collect()))
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

/// Mark the end of the warm-up: the loop's wall time so far (output and checkpoints
/// excluded), the stage timers and the workers' busy counters.
fn mark_warmup(timing: &mut Timing, sim: &Simulation, wall_s: f64) {
    timing.warmup_wall_s = wall_s;
    timing.warmup_times = *sim.times();
    timing.warmup_busy = sim.worker_busy();
}

/// What a run carries besides the simulation while it steps, from its start (or its
/// checkpoint) to its summary; a checkpoint saves it as [`Carried`].
pub struct Carry {
    /// The run's log: initial grid, start, timing so far, checkpoints and restarts before
    /// this process, energy history, the bar's initial figures.
    pub log: RunLog,
    /// The impact's cloud history, the plate's shock tracker.
    pub tracking: Tracking,
}

impl Carry {
    /// The carry of a checkpoint, on the scenario's geometries.
    pub fn restored(c: Carried, impact: Option<ImpactGeometry>, plate: Option<PlateGeometry>) -> Result<Self> {
        Ok(Self { log: c.log, tracking: Tracking::restored(c.cloud, c.shock_path, impact, plate)? })
    }

    /// What a checkpoint saves now: the carry with the timing and the report as of now,
    /// and the snapshots written.
    fn saved(&self, timing: Timing, report: CheckpointReport, outputs: &Outputs) -> Carried {
        let (cloud, shock_path) = self.tracking.saved();
        Carried {
            log: RunLog { timing, report, ..self.log.clone() },
            cloud,
            shock_path,
            snapshots: outputs
                .snapshots()
                .map(|w| w.written().into_iter().map(|(step, time, file)| SavedSnapshot { step, time, file }).collect())
                .unwrap_or_default(),
        }
    }
}

/// The checkpoint report as of now: the restored one plus this process's checkpoints.
fn report_now(base: &CheckpointReport, ck: Option<&Checkpoints>) -> CheckpointReport {
    let mut r = base.clone();
    if let Some(c) = ck {
        r.written += c.written;
        r.write_s += c.writer.spent.as_secs_f64();
        if c.written > 0 {
            r.last_bytes = c.last_bytes;
        }
    }
    r
}

/// This process's checkpoints: the writer and what it wrote.
pub struct Checkpoints {
    /// The writer.
    pub writer: Checkpointer,
    written: u64,
    last_bytes: u64,
}

impl Checkpoints {
    /// Checkpoints by `writer`, none written yet.
    pub fn new(writer: Checkpointer) -> Self {
        Self { writer, written: 0, last_bytes: 0 }
    }
}

/// What the stepping loop reads besides the simulation.
struct LoopContext<'a> {
    spec: &'a RunSpec,
    pool: &'a PinnedPool,
    interrupted: &'a AtomicBool,
    progress: Option<&'a Progress>,
    geometry: Option<&'a ImpactGeometry>,
}

/// Step until the end time or the step limit (or Ctrl-C, or a solver error), writing
/// checkpoints when due. The whole loop runs on the pool's first worker (one hand-over to
/// the pool per run, not per step); the solver's parallel phases broadcast from there.
/// Returns why it stopped; `carry.log.timing` holds the loop's timing (output and checkpoint
/// writes excluded, added to what a checkpoint carried). `ranks`: what the tracking
/// measures with.
fn step_loop(
    ctx: &LoopContext<'_>,
    sim: &mut Simulation,
    outputs: &mut Outputs,
    carry: &mut Carry,
    mut checkpoints: Option<&mut Checkpoints>,
    ranks: &mut dyn Collectives,
) -> Result<EndReason> {
    let (base_wall, base_output) = (carry.log.timing.wall_s, carry.log.timing.output_s);
    let warmup = carry.log.timing.warmup_steps;
    let mut warm_done = warmup == 0 || sim.steps() >= warmup;
    let budget = &ctx.spec.budget;
    let loop_start = Instant::now();
    // The loop's wall time: what a checkpoint carried plus this process's loop, less its
    // output and checkpoint writes.
    let wall = |outputs: &Outputs, ck: Option<&Checkpoints>| {
        let left_out = outputs.spent + ck.map_or(Duration::ZERO, |c| c.writer.spent);
        base_wall + loop_start.elapsed().saturating_sub(left_out).as_secs_f64()
    };
    let end_reason = ctx.pool.pool.install(|| -> Result<EndReason> {
        loop {
            if let Some(reason) = reached(budget, sim) {
                return Ok(reason);
            }
            if ctx.interrupted.load(Ordering::Relaxed) {
                ctx.progress.inspect(|p| p.bar.abandon());
                return Err(Interrupted(sim.steps()).into());
            }
            let dt_max = budget.end_time_s.map_or(f64::INFINITY, |end| end - sim.time());
            if let Err(e) = sim.step(&ctx.pool.pool, dt_max) {
                ctx.progress.inspect(|p| p.bar.abandon());
                return Err(anyhow::Error::new(e).context(format!(
                    "the simulation failed in the step starting at t = {:.6e} s ({}, strategy {}, {} thread(s)); no summary written",
                    sim.time(),
                    ctx.spec.scenario.describe(),
                    ctx.spec.strategy.name(),
                    ctx.spec.threads
                )));
            }
            record(&mut carry.log.history, sim);
            let t0 = Instant::now();
            carry.tracking.observe(sim, ranks)?;
            outputs.spent += t0.elapsed();
            if !warm_done && sim.steps() >= warmup {
                warm_done = true;
                mark_warmup(&mut carry.log.timing, sim, wall(outputs, checkpoints.as_deref()));
            }
            ctx.progress.inspect(|p| p.update(sim));
            outputs.after_step(sim, ctx.geometry)?;
            if let Some(ck) = checkpoints.as_deref_mut() {
                // No checkpoint of the final state: the summary follows at once.
                if reached(budget, sim).is_none() && ck.writer.due(sim, ranks)? {
                    let timing = Timing {
                        wall_s: wall(outputs, Some(ck)),
                        output_s: base_output + outputs.spent.as_secs_f64(),
                        ..carry.log.timing.clone()
                    };
                    let mut report = report_now(&carry.log.report, Some(ck));
                    report.written += 1;
                    let program = carry.saved(timing, report, outputs);
                    if let Some(bytes) = ck.writer.write(ctx.spec, sim, program, ranks)? {
                        ck.written += 1;
                        ck.last_bytes = bytes;
                    }
                }
            }
        }
    })?;
    let wall_s = wall(outputs, checkpoints.as_deref());
    carry.log.timing.wall_s = wall_s;
    if !warm_done {
        // The run ended inside the warm-up: no steady-state steps.
        mark_warmup(&mut carry.log.timing, sim, wall_s);
    }
    Ok(end_reason)
}

/// Where a run's spec comes from.
pub enum Request {
    /// `mpm run <scenario> --flags`.
    Flags(Box<crate::cli::Scenario>),
    /// `mpm run --spec FILE [--json FILE] [--quiet]`.
    File {
        /// The spec file.
        path: PathBuf,
        /// `--json`, replacing the spec's `outputs.json`.
        json: Option<PathBuf>,
        /// `--quiet`.
        quiet: bool,
    },
}

impl Request {
    /// The ranks asked for before MPI starts (the spec's, or `--ranks`), and the spec read
    /// from its file.
    fn before_start(&self) -> Result<(Option<usize>, Option<RunSpec>)> {
        match self {
            Request::Flags(sc) => Ok((sc.options().ranks.map(|r| r as usize), None)),
            Request::File { path, json, quiet } => {
                let mut spec = RunSpec::read(path)?;
                if json.is_some() {
                    spec.outputs.json.clone_from(json);
                }
                spec.outputs.quiet |= *quiet;
                Ok((Some(spec.ranks), Some(spec)))
            }
        }
    }
}

/// `mpm run ...`: the whole run, from its spec (read, or built from the flags on the
/// launcher's rank count) to its summary.
pub fn run(request: Request, control: Control, command_line: Vec<String>) -> Result<()> {
    let started_unix_s = mpm_cli::summary::unix_now();
    let (requested, from_file) = request.before_start()?;
    let mut ranks = Ranks::start(requested)?;
    let lead = ranks.rank() == 0;
    let mut spec = match (from_file, &request) {
        (Some(spec), _) => spec,
        (None, Request::Flags(sc)) => sc.spec(ranks.size())?,
        (None, Request::File { .. }) => unreachable!("a spec file is read before MPI starts"),
    };
    if control.print_spec {
        if lead {
            print!("{}", spec.to_toml());
        }
        return Ok(());
    }
    let mut plan = Plan::check(&spec, control.force)?;
    // Rank 0 holds the checkpoint folder for the run; every rank checks it is unused.
    let _lock = match &spec.outputs.checkpoint {
        Some(c) if lead => Some(Folder::new(&c.dir).lock(Duration::ZERO)?),
        _ => None,
    };
    if let Some(c) = &spec.outputs.checkpoint {
        mpm_cli::checkpoint::refuse_used_folder(&c.dir, &mpm_cli::checkpoint::run_key(&spec))?;
    }
    let (cpus, rank_oversubscribed) = place_rank(&spec, &mut plan, &ranks)?;
    let mut outputs = if lead { Outputs::open(&spec)? } else { Outputs::none() };
    let pool = start_pool(spec.threads, cpus.as_deref())?;
    let (Prepared { setup, impact, plate }, exchange) =
        ranks.build(&spec.scenario, spec.physics.eos, spec.rank_layout, spec.split_wait, false)?;
    let taylor = matches!(spec.scenario, mpm_spec::Scenario::Taylor(_));
    let model_name = setup.model.clone();
    // A paired run builds its one-thread reference from the same set-up.
    let reference_setup = spec.paired.map(|_| setup.clone());
    let sim = simulation(&spec, setup, exchange)?;
    let (cells, nodes) = (sim.global_geom().num_cells(), sim.global_geom().num_nodes());
    let warmup = spec.budget.warmup.unwrap_or_else(|| spec.default_warmup(sim.dt_first()));
    spec.budget.warmup = Some(warmup);
    let checkpoints = match &spec.outputs.checkpoint {
        Some(c) => Some(Checkpoints::new(Checkpointer::new(
            &c.dir,
            c.every,
            &spec,
            ranks.rank(),
            mpm_cli::identity::this_binary_sha256(),
        )?)),
        None => None,
    };
    let mut history = HistoryRecorder::new();
    record(&mut history, &sim);
    let initial_taylor = bar_figures(taylor, &sim, ranks.collectives())?;
    let mut tracking = Tracking::new(impact, plate)?;
    tracking.observe(&sim, ranks.collectives())?;
    outputs.initial(&sim)?;
    let log = RunLog {
        cells,
        nodes,
        started_unix_s,
        command_line,
        timing: Timing { warmup_steps: warmup, ..Timing::default() },
        report: CheckpointReport::default(),
        history,
        initial_taylor,
    };
    let carry = Carry { log, tracking };
    let run = Ready {
        spec,
        plan,
        rank_oversubscribed,
        pool,
        sim,
        outputs,
        carry,
        impact,
        plate,
        taylor,
        model_name,
        checkpoints,
        restart: None,
        reference_setup,
    };
    go(run, &mut ranks)
}

/// A run ready to step: fresh from its spec ([`run`]) or taken back from a checkpoint
/// (`resume`).
pub struct Ready {
    /// The run, resolved.
    pub spec: RunSpec,
    /// What the machine said about it.
    pub plan: Plan,
    /// Whether this rank shares CPUs with another.
    pub rank_oversubscribed: bool,
    /// The pinned pool.
    pub pool: PinnedPool,
    /// The simulation.
    pub sim: Simulation,
    /// Its outputs.
    pub outputs: Outputs,
    /// What the program carries.
    pub carry: Carry,
    /// Impact: the geometry.
    pub impact: Option<ImpactGeometry>,
    /// Plate: the geometry.
    pub plate: Option<PlateGeometry>,
    /// Whether the scenario is the Taylor bar.
    pub taylor: bool,
    /// The model's label.
    pub model_name: String,
    /// The run's checkpoints.
    pub checkpoints: Option<Checkpoints>,
    /// A restart: when this process started (its set-up until the loop is booked as the
    /// restart's).
    pub restart: Option<Instant>,
    /// A paired run ([`RunSpec::paired`]): the set-up of its one-thread reference.
    pub reference_setup: Option<mpm_core::Setup>,
}

/// Step a ready run to its end, then measure, write and print its summary.
pub fn go(run: Ready, ranks: &mut Ranks) -> Result<()> {
    let Ready {
        spec,
        plan,
        rank_oversubscribed,
        pool,
        mut sim,
        mut outputs,
        mut carry,
        impact,
        plate,
        taylor,
        model_name,
        mut checkpoints,
        restart,
        reference_setup,
    } = run;
    let lead = ranks.rank() == 0;
    let quiet = spec.outputs.quiet;
    let interrupted = install_interrupt_handler();
    let progress = Progress::new(quiet || !lead, spec.budget.end_time_s, spec.budget.steps, &sim);
    let ctx = LoopContext {
        spec: &spec,
        pool: &pool,
        interrupted: &interrupted,
        progress: progress.as_ref(),
        geometry: impact.as_ref(),
    };
    if let Some(t0) = restart {
        carry.log.report.restart_setup_s += t0.elapsed().as_secs_f64();
    }
    let (end_reason, noise, paired) = match reference_setup {
        Some(setup) => {
            let warmup = carry.log.timing.warmup_steps;
            let (s, out) = crate::paired::run(&spec, sim, &pool, setup, sim_config(&spec), warmup, &interrupted)?;
            sim = s;
            record(&mut carry.log.history, &sim);
            carry.tracking.observe(&sim, ranks.collectives())?;
            carry.log.timing = out.timing;
            (out.end_reason, out.noise, Some(out.report))
        }
        None => {
            // What each worker got of the loop's wall time (the noise a run can see).
            let mut usage = UsageMeter::new(spec.threads, &pool.observed_cpus());
            usage.begin(&pool.pool);
            let end_reason =
                step_loop(&ctx, &mut sim, &mut outputs, &mut carry, checkpoints.as_mut(), ranks.collectives())?;
            usage.end(&pool.pool);
            (end_reason, usage.report(MIN_CPU_SHARE), None)
        }
    };
    // The final figures, measured once: the summary's, and the history's last sample.
    let figures = FinalFigures::measure(&sim, taylor, &carry.tracking, ranks.collectives())?;
    carry.tracking.finish(&sim, &figures);
    outputs.finish(&sim, impact.as_ref(), quiet)?;
    let cloud_history = carry.tracking.cloud.take().map(|(h, _)| h);
    if let Some(h) = &cloud_history {
        outputs.history_plot(h, quiet)?;
    }
    carry.log.timing.output_s += outputs.spent.as_secs_f64();
    if let Some(p) = &progress {
        p.bar.finish_and_clear();
    }
    let report = report_now(&carry.log.report, checkpoints.as_ref());

    // Rank 0's summary, built before a state dump can release the grid's arrays.
    let summary = lead.then(|| {
        summary::build(
            &sim,
            RunContext {
                spec: &spec,
                model_name,
                cells: carry.log.cells,
                nodes: carry.log.nodes,
                end_reason,
                timing: &carry.log.timing,
                pool: &pool,
                available_cores: plan.available_cores,
                oversubscribed: plan.oversubscribed,
                history: carry.log.history.finish(200),
                failed_particles: figures.failed,
                taylor: carry.log.initial_taylor.zip(figures.taylor),
                cloud: figures.cloud,
                cloud_history,
                plate: plate.map(|g| (g, figures.plate)),
                command_line: carry.log.command_line,
                started_unix_s: carry.log.started_unix_s,
                checkpoint: (report.written > 0 || report.restarts > 0).then_some(report),
            },
        )
    });
    if let Some(path) = &spec.outputs.dump_state {
        ranks.dump_state(&mut sim, path)?;
    }
    // Every rank's peak memory, read after the last thing the run holds memory for.
    let reports = match ranks.size() {
        1 => None,
        _ => ranks.gather_reports(rank_report(&sim, &pool, ranks, rank_oversubscribed))?,
    };
    let Some(mut summary) = summary else { return Ok(()) };
    summary::finish(&mut summary, reports, noise, paired);
    outputs.commit_json(&summary)?;
    if !quiet {
        print_human(&summary, spec.outputs.json.as_deref(), outputs.snapshots());
    }
    Ok(())
}
