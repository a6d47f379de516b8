//! A run ready to step ([`Ready`], fresh or continued from a checkpoint) from its first step
//! to its summary ([`go`]): the stepping loop ([`step_loop`], writing checkpoints when due)
//! or the paired measurement, the final figures, then the summary built, written and
//! printed.

use crate::checkpointing::{Carried, Checkpointer, RunLog, SavedSnapshot};
use crate::human::print_human;
use crate::interrupt::{Interrupted, LastCheckpoint, Requests};
use crate::machine::Plan;
use crate::output::Outputs;
use crate::progress::Progress;
use crate::ranks::Ranks;
use crate::solver::sim_config;
use crate::tracking::{FinalFigures, Tracking};
use anyhow::Result;
use mpm_cli::summary::{self, peak_rss_bytes, HistoryRecorder, RunContext, Timing};
use mpm_core::scenario::impact::{History, ImpactGeometry};
use mpm_core::scenario::plate::PlateGeometry;
use mpm_core::{Collectives, Simulation};
use mpm_host::pinning::PinnedPool;
use mpm_host::slowdown::StepSlowdown;
use mpm_host::usage::UsageMeter;
use mpm_spec::spec::Budget;
use mpm_spec::summary::{
    CheckpointReport, EndReason, HistoryPoint, NoiseReport, PairedReport, RankReport, MIN_CPU_SHARE,
};
use mpm_spec::RunSpec;
use std::time::{Duration, Instant};

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

/// Add the current state to the energy history.
pub fn record(history: &mut HistoryRecorder, sim: &Simulation) {
    let d = sim.diagnostics();
    history.record(HistoryPoint { step: sim.steps(), time: sim.time(), kinetic: d.kinetic, internal: d.internal });
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
    /// The checkpoints `spec` asks for (none when it asks for none), written by `rank` of
    /// the binary whose SHA-256 `binary_sha256` gives; none written yet.
    pub fn of(spec: &RunSpec, rank: usize, binary_sha256: impl FnOnce() -> String) -> Result<Option<Self>> {
        let Some(c) = &spec.outputs.checkpoint else { return Ok(None) };
        let writer = Checkpointer::new(&c.dir, c.every, spec, rank, binary_sha256())?;
        Ok(Some(Self { writer, written: 0, last_bytes: 0 }))
    }
}

/// What the stepping loop reads besides the simulation.
struct LoopContext<'a> {
    spec: &'a RunSpec,
    pool: &'a PinnedPool,
    requests: &'a Requests,
    progress: Option<&'a Progress>,
    geometry: Option<&'a ImpactGeometry>,
}

/// Step until the end time or the step limit (or Ctrl-C, or a solver error), writing
/// checkpoints when due (and a last one when a signal asks for it: [`checkpoint_after_step`]). The whole loop runs on the pool's first worker (one hand-over to
/// the pool per run, not per step); the solver's parallel phases broadcast from there.
/// Returns why it stopped; `carry.log.timing` holds the loop's timing (output and checkpoint
/// writes excluded, added to what a checkpoint carried). `ranks`: what the tracking
/// measures with. `slowdown`: the injected step slowdown after every step (a test knob),
/// inside the loop's timing.
fn step_loop(
    ctx: &LoopContext<'_>,
    sim: &mut Simulation,
    outputs: &mut Outputs,
    carry: &mut Carry,
    mut checkpoints: Option<&mut Checkpoints>,
    ranks: &mut dyn Collectives,
    slowdown: &mut Option<StepSlowdown>,
) -> Result<EndReason> {
    let base_wall = carry.log.timing.wall_s;
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
            if ctx.requests.stop_now() {
                ctx.progress.inspect(|p| p.bar.abandon());
                return Err(Interrupted(sim.steps()).into());
            }
            let dt_max = budget.end_time_s.map_or(f64::INFINITY, |end| end - sim.time());
            if let Err(e) = step_once(sim, dt_max, ctx.pool, slowdown) {
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
                let wall_s = wall(outputs, Some(ck));
                checkpoint_after_step(ctx, sim, outputs, carry, ck, ranks, wall_s)?;
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

/// After a step of a run with checkpoints: the checkpoint when due, or the last one when
/// SIGTERM or SIGUSR1 asked for it on any rank (collective over ranks every step: the ranks
/// stop after the same step), then the error the run stops with ([`LastCheckpoint`], or
/// [`Interrupted`] when it could not be written). None of the final state: the summary
/// follows at once. `wall_s`: the loop's wall time so far.
fn checkpoint_after_step(
    ctx: &LoopContext<'_>,
    sim: &Simulation,
    outputs: &Outputs,
    carry: &Carry,
    ck: &mut Checkpoints,
    ranks: &mut dyn Collectives,
    wall_s: f64,
) -> Result<()> {
    if reached(&ctx.spec.budget, sim).is_some() {
        return Ok(());
    }
    let mut last = [u64::from(ctx.requests.last_checkpoint())];
    if ranks.ranks() > 1 {
        ranks.sum_counts(&mut last)?;
    }
    let last = last[0] > 0;
    if !last && !ck.writer.due(sim, ranks)? {
        return Ok(());
    }
    let timing = Timing {
        wall_s,
        output_s: carry.log.timing.output_s + outputs.spent.as_secs_f64(),
        ..carry.log.timing.clone()
    };
    let mut report = report_now(&carry.log.report, Some(ck));
    report.written += 1;
    let program = carry.saved(timing, report, outputs);
    let written = ck.writer.write(ctx.spec, sim, program, ranks)?;
    if let Some(bytes) = written {
        ck.written += 1;
        ck.last_bytes = bytes;
    }
    if !last {
        return Ok(());
    }
    ctx.progress.inspect(|p| p.bar.abandon());
    let dir = ctx.spec.outputs.checkpoint.as_ref().map_or_else(String::new, |c| c.dir.display().to_string());
    Err(match written {
        Some(_) => LastCheckpoint { step: sim.steps(), dir }.into(),
        None => Interrupted(sim.steps()).into(),
    })
}

/// One step, then the injected step slowdown (a test knob) when there is one.
fn step_once(
    sim: &mut Simulation,
    dt_max: f64,
    pool: &PinnedPool,
    slowdown: &mut Option<StepSlowdown>,
) -> Result<(), mpm_core::SimError> {
    let start = Instant::now();
    sim.step(dt_max)?;
    if let Some(s) = slowdown {
        s.after_step(&pool.pool, start.elapsed().as_secs_f64());
    }
    Ok(())
}

/// A run ready to step, set up by [`crate::start::start`]: fresh from its spec or taken back
/// from a checkpoint.
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

/// How the stepping ended: why, what the workers got of the wall time, a paired run's
/// blocks and its reference's model.
struct Stepped {
    end_reason: EndReason,
    noise: Option<NoiseReport>,
    paired: Option<PairedReport>,
    /// A paired run's one-thread reference's model bytes (0 otherwise).
    reference_memory_bytes: usize,
    /// Seconds the injected step slowdown added in this process (a test knob).
    injected_step_s: Option<f64>,
}

/// Step a ready run to its end, then measure, write and print its summary.
pub fn go(run: Ready, ranks: &mut Ranks) -> Result<()> {
    let quiet = run.spec.outputs.quiet;
    let requests = Requests::arm(run.checkpoints.is_some());
    let budget = &run.spec.budget;
    let progress = Progress::new(quiet || ranks.rank() != 0, budget.end_time_s, budget.steps, &run.sim);
    let (mut run, stepped) = step(run, &requests, progress.as_ref(), ranks)?;
    // The final figures, measured once: the summary's, and the history's last sample.
    let figures = FinalFigures::measure(&run.sim, run.taylor, &run.carry.tracking, ranks.collectives())?;
    run.carry.tracking.finish(&run.sim, &figures);
    run.outputs.finish(&run.sim, run.impact.as_ref(), quiet)?;
    let cloud_history = run.carry.tracking.cloud.take().map(|(h, _)| h);
    if let Some(h) = &cloud_history {
        run.outputs.history_plot(h, quiet)?;
    }
    run.carry.log.timing.output_s += run.outputs.spent.as_secs_f64();
    if let Some(p) = &progress {
        p.bar.finish_and_clear();
    }
    summarize(run, stepped, figures, cloud_history, ranks)
}

/// Step the run to its end: the paired measurement when the spec asks for one, else the
/// stepping loop, with what each worker got of its wall time (the noise a run can see).
fn step(
    mut run: Ready,
    requests: &Requests,
    progress: Option<&Progress>,
    ranks: &mut Ranks,
) -> Result<(Ready, Stepped)> {
    if let Some(t0) = run.restart {
        run.carry.log.report.restart_setup_s += t0.elapsed().as_secs_f64();
    }
    let stepped = match run.reference_setup.take() {
        Some(setup) => {
            let warmup = run.carry.log.timing.warmup_steps;
            let config = sim_config(&run.spec);
            let (sim, out) = crate::paired::run(&run.spec, run.sim, &run.pool, setup, config, warmup, requests)?;
            run.sim = sim;
            record(&mut run.carry.log.history, &run.sim);
            run.carry.tracking.observe(&run.sim, ranks.collectives())?;
            run.carry.log.timing = out.timing;
            Stepped {
                end_reason: out.end_reason,
                noise: out.noise,
                paired: Some(out.report),
                reference_memory_bytes: out.reference_memory_bytes,
                injected_step_s: out.injected_step_s,
            }
        }
        None => {
            let ctx =
                LoopContext { spec: &run.spec, pool: &run.pool, requests, progress, geometry: run.impact.as_ref() };
            let mut usage = UsageMeter::new(run.spec.threads, &run.pool.observed_cpus());
            usage.begin(&run.pool.pool);
            let (sim, outputs, carry) = (&mut run.sim, &mut run.outputs, &mut run.carry);
            let mut slow = run.spec.inject_step_slowdown.map(StepSlowdown::new);
            let (ck, collectives) = (run.checkpoints.as_mut(), ranks.collectives());
            let end_reason = step_loop(&ctx, sim, outputs, carry, ck, collectives, &mut slow)?;
            usage.end(&run.pool.pool);
            let injected_step_s = slow.map(|s| s.total_s);
            Stepped {
                end_reason,
                noise: usage.report(MIN_CPU_SHARE),
                paired: None,
                reference_memory_bytes: 0,
                injected_step_s,
            }
        }
    };
    Ok((run, stepped))
}

/// Build rank 0's summary of a run stepped to its end, dump the state when asked, gather
/// every rank's report, then write the summary and print it.
fn summarize(
    run: Ready,
    stepped: Stepped,
    figures: FinalFigures,
    cloud_history: Option<History>,
    ranks: &mut Ranks,
) -> Result<()> {
    let Ready {
        spec,
        plan,
        rank_oversubscribed,
        pool,
        mut sim,
        mut outputs,
        carry,
        plate,
        model_name,
        checkpoints,
        ..
    } = run;
    let report = report_now(&carry.log.report, checkpoints.as_ref());
    // Rank 0's summary, built before a state dump can release the grid's arrays.
    let summary = (ranks.rank() == 0).then(|| {
        summary::build(
            &sim,
            RunContext {
                spec: &spec,
                model_name,
                cells: carry.log.cells,
                nodes: carry.log.nodes,
                end_reason: stepped.end_reason,
                timing: &carry.log.timing,
                pool: &pool,
                available_cores: plan.available_cores,
                oversubscribed: plan.oversubscribed,
                cpu_quota: plan.cpu_quota,
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
    summary::finish(&mut summary, reports, stepped.noise, stepped.paired);
    summary.figures.memory.model_memory_bytes += stepped.reference_memory_bytes;
    summary.figures.injected_step_s = stepped.injected_step_s;
    outputs.commit_json(&summary)?;
    if !spec.outputs.quiet {
        print_human(&summary, spec.outputs.json.as_deref(), outputs.snapshots());
    }
    Ok(())
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
        peak_rss_bytes: peak_rss_bytes(),
    }
}
