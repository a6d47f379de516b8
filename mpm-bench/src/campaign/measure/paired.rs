//! `mpm-bench paired`: parallel efficiency as paired ratios measured inside one process.
//!
//! # Why
//!
//! A campaign times each configuration in its own process, minutes apart. On a shared or
//! virtualised host the speed of a CPU drifts on that time scale: on the 2-core development
//! VM a serial Model 2 step took anywhere from 47 to 55 ms between runs, and a 2-thread
//! step 26 to 34 ms, sometimes because one of the two virtual CPUs ran at half speed for a
//! whole run (the load imbalance in the JSON summary shows it). The efficiency
//! `T1 / (T x T_T)` of two such numbers inherits both errors.
//!
//! Here every configuration lives in the same process at the same time: the serial solver,
//! and for each strategy its 1-thread and its `T`-thread solver, all built from the same
//! set-up. They advance in *blocks* of a few steps, one configuration after the other, the
//! order rotated from block to block. Block `b` of every configuration covers the same
//! simulated steps (the solvers agree to round-off), so the ratio
//! `e_b = t1_b / (T x tT_b)` of two blocks a few hundred milliseconds apart compares the same
//! work under nearly the same host conditions. The blocks run through the solver program's
//! own alternation ([`mpm_host::paired`], which `mpm run` uses for a campaign's paired cells);
//! this module measures, [`crate::analysis::paired::report`] estimates (the median of the
//! `e_b` with a percentile-bootstrap interval over the blocks, the efficiency of the medians
//! and of the best blocks).
//!
//! One process's blocks do not show the spread between processes: on the development VM two
//! such measurements back to back gave 0.62 [0.60, 0.82] and then 0.94 [0.88, 0.96] for AE on
//! Model 1. For an interval that holds across processes, measure paired cells in a campaign
//! (several short processes per cell, `paired = { blocks = N }` in the preset), whose
//! analysis resamples processes, not only blocks.
//!
//! The 1-thread solvers run on a pool of one worker pinned to the first CPU of the
//! placement, the `T`-thread solvers on a pool pinned by the placement (worker `j` on its
//! `j`-th CPU). Build the harness optimised (`--profile o3`): the solver runs in this
//! process, so this binary's optimisation level is the one measured.

use crate::campaign::plan::memory::{estimate_memory, memory_here};
use crate::machine::placement::PinPolicy;
use crate::machine::topology::{human_bytes, Machine};
use crate::util::now_rfc3339;
use anyhow::{bail, Context, Result};
use indicatif::{ProgressBar, ProgressStyle};
use mpm_core::scenario::taylor::TaylorBar;
use mpm_core::{SimConfig, Simulation, Strategy};
use mpm_host::paired::{alternate, max_position_difference, unlimited, Contender};
use mpm_host::pinning::{self, PinnedPool};
use serde::Serialize;
use std::path::PathBuf;
use std::sync::Arc;

/// Measure parallel efficiency as paired ratios of interleaved blocks in one process.
///
/// Every configuration (serial; each strategy at 1 and at `--threads` threads) runs the
/// same Taylor bar model in this process, advancing `--block-steps` steps at a time in
/// rotating order, so the 1-thread and the `T`-thread block of each pair are timed a few
/// hundred milliseconds apart. On a noisy or shared machine this gives a much tighter
/// efficiency than separate runs. Build with `--profile o3`.
#[derive(Debug, Clone)]
pub struct PairedOptions {
    /// Taylor bar model, 1-4 (Model 4 needs several GiB per configuration).
    pub model: u8,
    /// Strategies to measure, comma-separated: ae, dd, dd-balanced, colour, atomic. Each
    /// after the first is also compared with the first at `--threads` threads, block by
    /// block (e.g. `dd,dd-balanced`: the cost or gain of balanced cuts).
    pub strategies: Vec<String>,
    /// Workers of the parallel configurations (the reference configurations use 1).
    pub threads: usize,
    /// Pinning: close, spread, none, or a CPU list such as 0,1. The 1-thread
    /// configurations run on the first CPU of the placement.
    pub pin: String,
    /// Paired samples: blocks per configuration.
    pub blocks: usize,
    /// Steps per configuration and block (default: enough for about 0.2 s of the serial
    /// solver, from its warm-up steps: short enough to follow the host's drift, long enough
    /// to time).
    pub block_steps: Option<u64>,
    /// Untimed steps of every configuration before the first block.
    pub warmup: u64,
    /// Write the measurement, every block included, as JSON.
    pub json: Option<PathBuf>,
    /// No progress bar.
    pub quiet: bool,
}

/// One strategy's blocks.
#[derive(Clone, Debug, Serialize)]
pub struct StrategyBlocks {
    /// A parallel strategy (`ae`, `dd`, `dd-balanced`, `colour`, `atomic`).
    pub strategy: Strategy,
    /// Seconds per step of the 1-thread configuration, per block.
    pub t1_s_per_step: Vec<f64>,
    /// Seconds per step of the `T`-thread configuration, per block.
    pub tt_s_per_step: Vec<f64>,
    /// Load imbalance of the `T`-thread configuration per block (largest worker busy time
    /// over the mean).
    pub block_imbalance: Vec<f64>,
    /// Largest position difference between the `T`-thread and the 1-thread solver at the
    /// end, relative to the bar length (round-off only: they must agree).
    pub max_position_difference: f64,
}

/// What one `mpm-bench paired` measured (the statistics are [`crate::analysis::paired`]'s).
#[derive(Clone, Debug, Serialize)]
pub struct PairedMeasurement {
    /// Taylor bar model.
    pub model: u8,
    /// Particles.
    pub particles: usize,
    /// Workers of the parallel configurations.
    pub threads: usize,
    /// Pinning policy label.
    pub pin: String,
    /// CPUs of the `T`-thread workers as observed (empty when not pinned).
    pub observed_cpus: Vec<usize>,
    /// CPU of the 1-thread worker as observed (empty when not pinned).
    pub observed_cpu_one: Vec<usize>,
    /// More workers than usable CPUs: the efficiency is not a scaling figure.
    pub oversubscribed: bool,
    /// Paired blocks.
    pub blocks: usize,
    /// Steps per configuration and block.
    pub block_steps: u64,
    /// Untimed steps before the first block.
    pub warmup_steps: u64,
    /// Seconds per step of the serial solver, per block.
    pub serial_s_per_step: Vec<f64>,
    /// One entry per strategy (left out of the JSON once the analysis has replaced it with
    /// the estimates).
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub strategies: Vec<StrategyBlocks>,
    /// This binary was built with debug assertions (its timings mean little).
    pub debug_build: bool,
    /// Git commit this binary (whose solver ran the blocks) was built from.
    pub git_commit: String,
    /// Its sources had uncommitted changes when it was built (`true` also when unknown): the
    /// build's state, not the state of whatever folder the command runs in.
    pub git_dirty: bool,
    /// When the measurement ended (RFC 3339, UTC).
    pub timestamp: String,
    /// The command line.
    pub command_line: String,
}

/// Target length of a serial block when `--block-steps` is not given (s).
const BLOCK_SECONDS: f64 = 0.2;

fn parse_strategies(list: &[String]) -> Result<Vec<Strategy>> {
    let mut out = Vec::new();
    for s in list {
        let st: Strategy = s.trim().to_ascii_lowercase().parse().map_err(|_| {
            anyhow::anyhow!(
                "unknown strategy '{s}' in --strategies: use {} or a list (ae,dd)",
                Strategy::parallel_names()
            )
        })?;
        if !st.is_parallel() {
            bail!(
                "--strategies takes {}; the serial solver is always measured as the reference",
                Strategy::parallel_names()
            );
        }
        if !out.contains(&st) {
            out.push(st);
        }
    }
    if out.is_empty() {
        bail!("--strategies is empty: use {} or a list such as ae,dd", Strategy::parallel_names());
    }
    Ok(out)
}

fn check_args(a: &PairedOptions) -> Result<()> {
    if !(1..=4).contains(&a.model) {
        bail!("unknown model {}: the Taylor bar has Models 1-4", a.model);
    }
    if a.threads < 2 {
        bail!("--threads {} has nothing to compare with the 1-thread run: use 2 or more", a.threads);
    }
    if a.blocks < 2 {
        bail!("--blocks {} gives no interval: use at least 2 (15 or more for a useful one)", a.blocks);
    }
    if a.block_steps == Some(0) {
        bail!("--block-steps must be at least 1");
    }
    if a.warmup == 0 {
        bail!("--warmup must be at least 1 (the first step of a run pays for its page faults)");
    }
    Ok(())
}

/// The 1-thread and the `T`-thread pool, pinned by `policy` (the 1-thread worker on the
/// placement's first CPU); a worker not where it was asked to be is an error.
struct Pools {
    one: PinnedPool,
    many: PinnedPool,
    oversubscribed: bool,
}

impl Pools {
    fn build(policy: &PinPolicy, threads: usize) -> Result<Self> {
        let machine = Machine::detect()?;
        machine.check_policy(policy)?;
        let placement = machine.place(policy, threads)?;
        let cpus = (!placement.cpus.is_empty()).then_some(placement.cpus.as_slice());
        let many = pinning::build_pool(threads, cpus)?;
        let one = pinning::build_pool(1, cpus.map(|c| &c[..1]))?;
        for p in [&many, &one] {
            let bad = p.mismatches();
            if !bad.is_empty() {
                bail!("pinning not as requested: {}", bad.join("; "));
            }
        }
        Ok(Self { one, many, oversubscribed: placement.oversubscribed })
    }

    fn of(&self, threads: usize) -> &PinnedPool {
        if threads == 1 {
            &self.one
        } else {
            &self.many
        }
    }
}

/// The configurations: serial, then each strategy at 1 and at `threads` threads, all from
/// the same Taylor bar set-up, refused up front when together they would not fit in memory.
#[allow(clippy::type_complexity)]
fn configurations<'p>(
    a: &PairedOptions,
    strategies: &[Strategy],
    pools: &'p Pools,
) -> Result<(Vec<(Strategy, usize)>, Vec<Contender<'p>>, usize)> {
    let mut configs: Vec<(Strategy, usize)> = vec![(Strategy::Serial, 1)];
    for &s in strategies {
        configs.push((s, 1));
        configs.push((s, a.threads));
    }
    let need: u64 =
        configs.iter().map(|&(s, t)| estimate_memory(mpm_spec::ScenarioKind::Taylor, u32::from(a.model), s, t)).sum();
    if let Some(here) = memory_here() {
        if need > here.bytes {
            bail!(
                "{} configurations of Model {} need about {}, more than the memory they may use here ({here}): \
                 measure one strategy (--strategies ae) or a smaller model",
                configs.len(),
                a.model,
                human_bytes(need),
            );
        }
    }
    let setup = TaylorBar { model: a.model, ..TaylorBar::default() }.setup()?;
    let particles = setup.particles.len();
    let solvers = configs
        .iter()
        .map(|&(strategy, threads)| {
            let (config, pool) = (SimConfig { strategy, ..SimConfig::default() }, pools.of(threads));
            Ok(Contender::new(Simulation::new(setup.clone(), config, Arc::clone(&pool.pool))?, pool))
        })
        .collect::<Result<_>>()?;
    Ok((configs, solvers, particles))
}

/// Untimed warm-up steps of every configuration (`labels`: strategy and threads of each
/// solver), then `blocks` rounds of timed blocks in rotating order. Returns the steps per
/// block (from the serial warm-up's speed unless `--block-steps` is given).
fn run_blocks(a: &PairedOptions, labels: &[(Strategy, usize)], solvers: &mut [Contender<'_>]) -> Result<u64> {
    let bar = if a.quiet { ProgressBar::hidden() } else { ProgressBar::new((a.blocks * solvers.len()) as u64) };
    bar.set_style(
        ProgressStyle::with_template("[{elapsed_precise}] {bar:24.cyan/blue} {pos}/{len} blocks ETA {eta} | {msg}")
            .expect("valid template")
            .progress_chars("=> "),
    );
    bar.set_message("warm-up");
    for (c, (strategy, threads)) in solvers.iter_mut().zip(labels) {
        c.warm_up(a.warmup, &unlimited).with_context(|| format!("{strategy} with {threads} thread(s) failed"))?;
    }
    let serial_step = solvers[0].warmup_wall_s / a.warmup as f64;
    let block_steps = a.block_steps.unwrap_or_else(|| (BLOCK_SECONDS / serial_step).ceil().clamp(1.0, 1000.0) as u64);
    alternate(solvers, a.blocks as u64, block_steps, &unlimited, |b, i| {
        let (strategy, threads) = labels[i];
        bar.set_message(format!("block {} of {}: {strategy} x{threads}", b + 1, a.blocks));
        bar.inc(1);
    })
    .context("a paired block failed")?;
    bar.finish_and_clear();
    Ok(block_steps)
}

/// Run the measurement (no printing; the statistics are [`crate::analysis::paired::report`]).
pub fn measure(a: &PairedOptions) -> Result<PairedMeasurement> {
    check_args(a)?;
    let strategies = parse_strategies(&a.strategies)?;
    let policy: PinPolicy = a.pin.parse()?;
    let pools = Pools::build(&policy, a.threads)?;
    let (labels, mut solvers, particles) = configurations(a, &strategies, &pools)?;
    let block_steps = run_blocks(a, &labels, &mut solvers)?;
    let serial = solvers[0].seconds.clone();
    let out = strategies
        .iter()
        .enumerate()
        .map(|(i, &s)| {
            let (one, many) = (&solvers[1 + 2 * i], &solvers[2 + 2 * i]);
            let dx = max_position_difference(&one.sim, &many.sim);
            StrategyBlocks {
                strategy: s,
                t1_s_per_step: one.seconds.clone(),
                tt_s_per_step: many.seconds.clone(),
                block_imbalance: many.imbalance.clone(),
                max_position_difference: dx / mpm_core::scenario::taylor::LENGTH,
            }
        })
        .collect();
    Ok(PairedMeasurement {
        model: a.model,
        particles,
        threads: a.threads,
        pin: policy.label(),
        observed_cpus: if pools.many.pinned() { pools.many.observed_cpus() } else { Vec::new() },
        observed_cpu_one: if pools.one.pinned() { pools.one.observed_cpus() } else { Vec::new() },
        oversubscribed: pools.oversubscribed,
        blocks: a.blocks,
        block_steps,
        warmup_steps: a.warmup,
        serial_s_per_step: serial,
        strategies: out,
        debug_build: cfg!(debug_assertions),
        git_commit: mpm_host::identity::GIT_COMMIT.to_string(),
        git_dirty: mpm_host::identity::GIT_DIRTY != "false",
        timestamp: now_rfc3339(),
        command_line: std::env::args().collect::<Vec<_>>().join(" "),
    })
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;

    pub(crate) fn args() -> PairedOptions {
        PairedOptions {
            model: 1,
            strategies: vec!["dd".into(), "dd-balanced".into()],
            threads: 2,
            pin: "none".into(),
            blocks: 3,
            block_steps: Some(1),
            warmup: 1,
            json: None,
            quiet: true,
        }
    }

    #[test]
    fn bad_arguments_are_refused_with_advice() {
        let cases: Vec<(PairedOptions, &str)> = vec![
            (PairedOptions { model: 5, ..args() }, "Models 1-4"),
            (PairedOptions { threads: 1, ..args() }, "use 2 or more"),
            (PairedOptions { blocks: 1, ..args() }, "at least 2"),
            (PairedOptions { block_steps: Some(0), ..args() }, "at least 1"),
            (PairedOptions { warmup: 0, ..args() }, "page faults"),
            (PairedOptions { strategies: vec!["xx".into()], ..args() }, "unknown strategy 'xx'"),
            (PairedOptions { strategies: vec!["serial".into()], ..args() }, "always measured"),
        ];
        for (a, want) in cases {
            let e = measure(&a).unwrap_err().to_string();
            assert!(e.contains(want), "{e}");
        }
    }
}
