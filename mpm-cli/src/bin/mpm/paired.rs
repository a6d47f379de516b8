//! A paired run (`paired` in the spec, `--paired-blocks N`): the spec's `T`-thread solver and
//! a one-thread solver of the same strategy, built from the same set-up in this process, the
//! one-thread worker pinned to the first CPU of the run's placement. Both take the warm-up
//! steps, then `blocks` timed blocks of `(steps - warmup) / blocks` steps each, alternating
//! ([`mpm_host::paired::alternate`]: the reference first in even blocks, second in odd ones).
//! The summary is the `T`-thread solver's (its times are its warm-up and its blocks); its
//! `paired` section holds both solvers' seconds per step per block and their ratio.

use crate::interrupt::{Interrupted, Requests};
use anyhow::{Context, Result};
use mpm_cli::summary::Timing;
use mpm_core::{SimConfig, Simulation};
use mpm_host::paired::{alternate, max_position_difference, Contender};
use mpm_host::pinning::{self, PinnedPool};
use mpm_spec::summary::{EndReason, NoiseReport, PairedReport, StageSeconds, MIN_CPU_SHARE};
use mpm_spec::RunSpec;
use std::sync::Arc;

/// What a paired run hands back to the summary.
pub struct PairedOutcome {
    /// Why it stopped (an end time before the last block, or the step budget).
    pub end_reason: EndReason,
    /// The `T`-thread solver's timing: its warm-up, then its blocks.
    pub timing: Timing,
    /// The blocks.
    pub report: PairedReport,
    /// The `T`-thread workers' CPU time against the wall time of their blocks.
    pub noise: Option<NoiseReport>,
    /// Bytes held by the one-thread reference's model (the summary's model memory counts
    /// both solvers).
    pub reference_memory_bytes: usize,
    /// Seconds the injected step slowdown added to the `T`-thread solver (a test knob).
    pub injected_step_s: Option<f64>,
}

/// The one-thread pool of the reference solver: pinned to `cpus[0]` when the run is pinned.
fn reference_pool(cpus: Option<&[usize]>) -> Result<PinnedPool> {
    let pool = pinning::build_pool(1, cpus.map(|c| &c[..1]))?;
    let bad = pool.mismatches();
    if !bad.is_empty() {
        eprintln!("warning: the paired reference's pinning is not as requested: {}", bad.join("; "));
    }
    Ok(pool)
}

/// Run the spec's paired measurement: `sim` (its `T`-thread solver, on `pool`) against a
/// one-thread solver of `setup`, with `warmup` warm-up steps each.
pub fn run(
    spec: &RunSpec,
    sim: Simulation,
    pool: &PinnedPool,
    setup: mpm_core::Setup,
    config: SimConfig,
    warmup: u64,
    requests: &Requests,
) -> Result<(Simulation, PairedOutcome)> {
    let p = spec.paired.context("not a paired run")?;
    let block_steps = spec.paired_block_steps(warmup)?;
    let one_pool = reference_pool(spec.cpus.as_deref())?;
    // The reference runs the same strategy on one worker, without the injected slowdown
    // (which needs a second worker anyway).
    let one_config = SimConfig { inject_slowdown: 0.0, ..config };
    let one = Simulation::new(setup, one_config, Arc::clone(&one_pool.pool))
        .context("cannot set up the paired reference (1 thread)")?;
    let end = spec.budget.end_time_s;
    let stop = |s: &Simulation| -> Option<f64> {
        if requests.stop_now() {
            return None;
        }
        match end {
            Some(e) if e - s.time() <= 1e-6 * s.dt_first() => None,
            Some(e) => Some(e - s.time()),
            None => Some(f64::INFINITY),
        }
    };
    // The step slowdown (a test knob) slows both alike: the time per step grows, their
    // ratio stays.
    let slow = spec.inject_step_slowdown;
    let mut solvers =
        [Contender::new(one, &one_pool).with_step_slowdown(slow), Contender::new(sim, pool).with_step_slowdown(slow)];
    for c in solvers.iter_mut() {
        c.warm_up(warmup, &stop).context("the paired run failed in its warm-up")?;
    }
    let (blocks, first) = alternate(&mut solvers, p.blocks, block_steps, &stop, |_, _| {})
        .context("the paired run failed in a timed block")?;
    if requests.stop_now() {
        return Err(Interrupted(solvers[1].sim.steps()).into());
    }
    let [one, many] = solvers;
    let t = spec.threads as f64;
    let block_efficiency: Vec<f64> = one.seconds.iter().zip(&many.seconds).map(|(a, b)| a / (t * b)).collect();
    let scale = many.sim.geom().dx * many.sim.geom().cells.iter().copied().max().unwrap_or(1) as f64;
    let max_position_difference = max_position_difference(&one.sim, &many.sim) / scale;
    let report = PairedReport {
        reference_threads: 1,
        blocks,
        block_steps,
        reference_cpus: one_pool.observed_cpus(),
        efficiency: PairedReport::geometric_mean(&block_efficiency),
        block_efficiency,
        reference_first: first.iter().map(|&i| i == 0).collect(),
        t1_s_per_step: one.seconds.clone(),
        tt_s_per_step: many.seconds.clone(),
        reference_steady_substages: StageSeconds::from_times(&one.sim.times().since(&one.times_at_start)),
        reference_noise: one.usage.report(MIN_CPU_SHARE),
        max_position_difference,
        ..PairedReport::default()
    };
    let timing = Timing {
        wall_s: many.warmup_wall_s + many.blocks_wall_s(),
        output_s: 0.0,
        warmup_steps: warmup,
        warmup_wall_s: many.warmup_wall_s,
        warmup_times: many.times_at_start,
        warmup_busy: many.busy_at_start.clone(),
    };
    let end_reason = if blocks < p.blocks { EndReason::EndTime } else { EndReason::StepLimit };
    let noise = many.usage.report(MIN_CPU_SHARE);
    let reference_memory_bytes = one.sim.memory_bytes();
    let injected_step_s = many.slowdown.as_ref().map(|s| s.total_s);
    Ok((many.sim, PairedOutcome { end_reason, timing, report, noise, reference_memory_bytes, injected_step_s }))
}
