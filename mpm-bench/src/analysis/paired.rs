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
//! work under nearly the same host conditions. The estimate is the median of the `e_b` with
//! a percentile-bootstrap interval ([`super::stats::bootstrap`]); the efficiency of the
//! medians and of the best blocks is printed beside it.
//!
//! The 1-thread solvers run on a pool of one worker pinned to the first CPU of the
//! placement, the `T`-thread solvers on a pool pinned by the placement (worker `j` on its
//! `j`-th CPU). Build the harness optimised (`--profile o3`): the solver runs in this
//! process, so this binary's optimisation level is the one measured.

use super::stats::{self, Estimate, StatsOptions};
use crate::campaign::manifest::git_info;
use crate::campaign::memory::{available_memory, estimate_memory};
use crate::machine::placement::PinPolicy;
use crate::machine::topology::{human_bytes, Machine};
use crate::util::{median, now_rfc3339};
use anyhow::{bail, Context, Result};
use indicatif::{ProgressBar, ProgressStyle};
use mpm_cli::pinning::{self, PinnedPool};
use mpm_core::scenario::taylor::TaylorBar;
use mpm_core::{SimConfig, Simulation, Strategy};
use mpm_spec::summary::load_imbalance;
use serde::Serialize;
use std::path::PathBuf;
use std::time::Instant;

/// Measure parallel efficiency as paired ratios of interleaved blocks in one process.
///
/// Every configuration (serial; each strategy at 1 and at `--threads` threads) runs the
/// same Taylor bar model in this process, advancing `--block-steps` steps at a time in
/// rotating order, so the 1-thread and the `T`-thread block of each pair are timed a few
/// hundred milliseconds apart. On a noisy or shared machine this gives a much tighter
/// efficiency than separate runs. Build with `--profile o3`.
#[derive(clap::Args, Debug, Clone)]
pub struct PairedArgs {
    /// Taylor bar model, 1-4 (Model 4 needs several GiB per configuration).
    #[arg(long, default_value_t = 2)]
    pub model: u8,
    /// Strategies to measure, comma-separated: ae, dd, dd-balanced. Each after the first is
    /// also compared with the first at `--threads` threads, block by block (e.g.
    /// `dd,dd-balanced`: the cost or gain of balanced cuts).
    #[arg(long, value_delimiter = ',', default_value = "ae,dd")]
    pub strategies: Vec<String>,
    /// Workers of the parallel configurations (the reference configurations use 1).
    #[arg(long, default_value_t = 2)]
    pub threads: usize,
    /// Pinning: close, spread, none, or a CPU list such as 0,1. The 1-thread
    /// configurations run on the first CPU of the placement.
    #[arg(long, default_value = "close")]
    pub pin: String,
    /// Paired samples: blocks per configuration.
    #[arg(long, default_value_t = 15)]
    pub blocks: usize,
    /// Steps per configuration and block (default: enough for about 0.2 s of the serial
    /// solver, from its warm-up steps: short enough to follow the host's drift, long enough
    /// to time).
    #[arg(long)]
    pub block_steps: Option<u64>,
    /// Untimed steps of every configuration before the first block.
    #[arg(long, default_value_t = 3)]
    pub warmup: u64,
    /// Write the measurement, every block included, as JSON.
    #[arg(long, value_name = "FILE")]
    pub json: Option<PathBuf>,
    /// No progress bar.
    #[arg(long)]
    pub quiet: bool,
}

/// One strategy's paired result.
#[derive(Clone, Debug, Serialize)]
pub struct PairedStrategy {
    /// `ae` or `dd`.
    pub strategy: Strategy,
    /// Seconds per step of the 1-thread configuration, per block.
    pub t1_s_per_step: Vec<f64>,
    /// Seconds per step of the `T`-thread configuration, per block.
    pub tt_s_per_step: Vec<f64>,
    /// Paired efficiency of each block, `t1_b / (T x tT_b)`.
    pub block_efficiency: Vec<f64>,
    /// Median of the paired efficiencies with its bootstrap interval.
    pub efficiency: Estimate,
    /// `median(t1) / (T x median(tT))`.
    pub efficiency_of_medians: f64,
    /// `min(t1) / (T x min(tT))`.
    pub efficiency_of_best: f64,
    /// Load imbalance of the `T`-thread configuration per block (largest worker busy time
    /// over the mean).
    pub block_imbalance: Vec<f64>,
    /// Median paired `t1_b / serial_b`: the strategy's 1-thread cost against the serial solver.
    pub one_thread_vs_serial: Estimate,
    /// Median paired `tT_b / tT_b(first strategy)`: this strategy's `T`-thread time against
    /// the first strategy's in the same blocks (`None` for the first strategy itself).
    pub tt_vs_first: Option<Estimate>,
    /// Largest position difference between the `T`-thread and the 1-thread solver at the
    /// end, relative to the bar length (round-off only: they must agree).
    pub max_position_difference: f64,
}

/// The whole measurement (the JSON file).
#[derive(Clone, Debug, Serialize)]
pub struct PairedReport {
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
    /// One entry per strategy.
    pub strategies: Vec<PairedStrategy>,
    /// This binary was built with debug assertions (its timings mean little).
    pub debug_build: bool,
    /// Git commit of the working directory, if any.
    pub git_commit: String,
    /// The working tree had uncommitted changes.
    pub git_dirty: bool,
    /// When the measurement ended (RFC 3339, UTC).
    pub timestamp: String,
    /// The command line.
    pub command_line: String,
}

/// Target length of a serial block when `--block-steps` is not given (s).
const BLOCK_SECONDS: f64 = 0.2;

/// One configuration under measurement.
struct Config {
    strategy: Strategy,
    threads: usize,
    sim: Simulation,
    seconds: Vec<f64>,
    imbalance: Vec<f64>,
}

fn parse_strategies(list: &[String]) -> Result<Vec<Strategy>> {
    let mut out = Vec::new();
    for s in list {
        let st: Strategy = s.trim().to_ascii_lowercase().parse().map_err(|_| {
            anyhow::anyhow!("unknown strategy '{s}' in --strategies: use ae, dd, dd-balanced or a list (ae,dd)")
        })?;
        if !st.is_parallel() {
            bail!("--strategies takes ae, dd and dd-balanced; the serial solver is always measured as the reference");
        }
        if !out.contains(&st) {
            out.push(st);
        }
    }
    if out.is_empty() {
        bail!("--strategies is empty: use ae, dd, dd-balanced or a list such as ae,dd");
    }
    Ok(out)
}

fn check_args(a: &PairedArgs) -> Result<()> {
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
fn configurations(a: &PairedArgs, strategies: &[Strategy]) -> Result<(Vec<Config>, usize)> {
    let mut configs: Vec<(Strategy, usize)> = vec![(Strategy::Serial, 1)];
    for &s in strategies {
        configs.push((s, 1));
        configs.push((s, a.threads));
    }
    let need: u64 =
        configs.iter().map(|&(s, t)| estimate_memory(mpm_spec::ScenarioKind::Taylor, u32::from(a.model), s, t)).sum();
    if let Some(avail) = available_memory() {
        if need > avail {
            bail!(
                "{} configurations of Model {} need about {}, but {} is available: measure one strategy \
                 (--strategies ae) or a smaller model",
                configs.len(),
                a.model,
                human_bytes(need),
                human_bytes(avail)
            );
        }
    }
    let setup = TaylorBar { model: a.model, ..TaylorBar::default() }.setup()?;
    let particles = setup.particles.len();
    let runs = configs
        .iter()
        .map(|&(strategy, threads)| {
            let config = SimConfig { strategy, threads, ..SimConfig::default() };
            Ok(Config {
                strategy,
                threads,
                sim: Simulation::new(setup.clone(), config)?,
                seconds: Vec::with_capacity(a.blocks),
                imbalance: Vec::with_capacity(a.blocks),
            })
        })
        .collect::<Result<_>>()?;
    Ok((runs, particles))
}

impl Config {
    /// Advance `steps` steps on its pool.
    fn advance(&mut self, pools: &Pools, steps: u64) -> Result<()> {
        let pool = &pools.of(self.threads).pool;
        let (strategy, threads) = (self.strategy, self.threads);
        pool.install(|| (0..steps).try_for_each(|_| self.sim.step(pool, f64::INFINITY)))
            .with_context(|| format!("{strategy} with {threads} thread(s) failed"))
    }

    /// One timed block: seconds per step and, for a team, the load imbalance of the block.
    fn block(&mut self, pools: &Pools, steps: u64) -> Result<()> {
        let busy0 = self.sim.worker_busy();
        let t0 = Instant::now();
        self.advance(pools, steps)?;
        self.seconds.push(t0.elapsed().as_secs_f64() / steps as f64);
        if let (Some(before), Some(after)) = (busy0, self.sim.worker_busy()) {
            let d: Vec<f64> = after.iter().zip(&before).map(|(x, y)| x - y).collect();
            self.imbalance.push(load_imbalance(&d).unwrap_or(f64::NAN));
        }
        Ok(())
    }
}

/// Untimed warm-up steps of every configuration, then `blocks` rounds of timed blocks in
/// rotating order. Returns the steps per block (from the serial warm-up's speed unless
/// `--block-steps` is given).
fn run_blocks(a: &PairedArgs, runs: &mut [Config], pools: &Pools) -> Result<u64> {
    let bar = if a.quiet { ProgressBar::hidden() } else { ProgressBar::new((a.blocks * runs.len()) as u64) };
    bar.set_style(
        ProgressStyle::with_template("[{elapsed_precise}] {bar:24.cyan/blue} {pos}/{len} blocks ETA {eta} | {msg}")
            .expect("valid template")
            .progress_chars("=> "),
    );
    bar.set_message("warm-up");
    let mut serial_step = f64::NAN;
    for (i, c) in runs.iter_mut().enumerate() {
        let t0 = Instant::now();
        c.advance(pools, a.warmup)?;
        if i == 0 {
            serial_step = t0.elapsed().as_secs_f64() / a.warmup as f64;
        }
    }
    let block_steps = a.block_steps.unwrap_or_else(|| (BLOCK_SECONDS / serial_step).ceil().clamp(1.0, 1000.0) as u64);
    let n = runs.len();
    for b in 0..a.blocks {
        for k in 0..n {
            let c = &mut runs[(b + k) % n];
            bar.set_message(format!("block {} of {}: {} x{}", b + 1, a.blocks, c.strategy, c.threads));
            c.block(pools, block_steps)?;
            bar.inc(1);
        }
    }
    bar.finish_and_clear();
    Ok(block_steps)
}

/// The paired efficiencies of one strategy from its 1-thread and `T`-thread blocks.
fn paired_strategy(s: Strategy, one: &Config, many: &Config, serial: &[f64], threads: usize) -> PairedStrategy {
    let opts = StatsOptions::default();
    let t = threads as f64;
    let ratios: Vec<f64> = one.seconds.iter().zip(&many.seconds).map(|(x, y)| x / (t * y)).collect();
    let vs_serial: Vec<f64> = one.seconds.iter().zip(serial).map(|(x, y)| x / y).collect();
    let min = |v: &[f64]| v.iter().copied().fold(f64::INFINITY, f64::min);
    let dx = one
        .sim
        .particles()
        .x
        .iter()
        .zip(&many.sim.particles().x)
        .flat_map(|(p, q)| (0..3).map(move |k| (p[k] - q[k]).abs()))
        .fold(0.0, f64::max);
    PairedStrategy {
        strategy: s,
        efficiency: stats::bootstrap(&[&ratios], &|m| m[0], &opts, &format!("paired-{s}")),
        efficiency_of_medians: median(&one.seconds) / (t * median(&many.seconds)),
        efficiency_of_best: min(&one.seconds) / (t * min(&many.seconds)),
        one_thread_vs_serial: stats::bootstrap(&[&vs_serial], &|m| m[0], &opts, &format!("vs-serial-{s}")),
        block_efficiency: ratios,
        block_imbalance: many.imbalance.clone(),
        tt_vs_first: None,
        t1_s_per_step: one.seconds.clone(),
        tt_s_per_step: many.seconds.clone(),
        max_position_difference: dx / mpm_core::scenario::taylor::LENGTH,
    }
}

/// Run the measurement (no printing).
pub fn measure(a: &PairedArgs) -> Result<PairedReport> {
    check_args(a)?;
    let strategies = parse_strategies(&a.strategies)?;
    let policy: PinPolicy = a.pin.parse()?;
    let pools = Pools::build(&policy, a.threads)?;
    let (mut runs, particles) = configurations(a, &strategies)?;
    let block_steps = run_blocks(a, &mut runs, &pools)?;
    let serial = runs[0].seconds.clone();
    let out = strategies
        .iter()
        .enumerate()
        .map(|(i, &s)| {
            let mut p = paired_strategy(s, &runs[1 + 2 * i], &runs[2 + 2 * i], &serial, a.threads);
            if i > 0 {
                let ratios: Vec<f64> =
                    runs[2 + 2 * i].seconds.iter().zip(&runs[2].seconds).map(|(x, y)| x / y).collect();
                let label = format!("vs-first-{s}");
                p.tt_vs_first = Some(stats::bootstrap(&[&ratios], &|m| m[0], &StatsOptions::default(), &label));
            }
            p
        })
        .collect();
    let git = git_info(None);
    Ok(PairedReport {
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
        git_commit: git.commit,
        git_dirty: git.dirty,
        timestamp: now_rfc3339(),
        command_line: std::env::args().collect::<Vec<_>>().join(" "),
    })
}

/// The human-readable result.
pub fn table(r: &PairedReport) -> String {
    // Worker by worker (an oversubscribed placement repeats CPUs).
    let cpus = |c: &[usize]| {
        if c.is_empty() {
            "unpinned".to_string()
        } else {
            c.iter().map(usize::to_string).collect::<Vec<_>>().join(",")
        }
    };
    let mut s = format!(
        "Model {} ({} particles): {} threads on CPUs {} against 1 thread on CPU {}; {} paired blocks of {} step(s) after {} warm-up step(s)\n",
        r.model,
        r.particles,
        r.threads,
        cpus(&r.observed_cpus),
        cpus(&r.observed_cpu_one),
        r.blocks,
        r.block_steps,
        r.warmup_steps
    );
    s.push_str(&format!("serial: {:.3} ms per step (median)\n", 1e3 * median(&r.serial_s_per_step)));
    s.push_str(&format!(
        "{:<11} {:>11} {:>11}  {:<24} {:>10} {:>8} {:>10} {:>16}\n",
        "strategy",
        "T1 ms/step",
        format!("T{} ms/step", r.threads),
        "efficiency, paired [95%]",
        "of medians",
        "of best",
        "imbalance",
        "T1 / serial"
    ));
    for p in &r.strategies {
        s.push_str(&format!(
            "{:<11} {:>11.3} {:>11.3}  {:<24} {:>10.3} {:>8.3} {:>10.3} {:>16}\n",
            p.strategy.name(),
            1e3 * median(&p.t1_s_per_step),
            1e3 * median(&p.tt_s_per_step),
            p.efficiency.show(3),
            p.efficiency_of_medians,
            p.efficiency_of_best,
            median(&p.block_imbalance),
            p.one_thread_vs_serial.show(3)
        ));
    }
    if let Some(first) = r.strategies.first() {
        for p in r.strategies.iter().filter_map(|p| p.tt_vs_first.as_ref().map(|e| (p, e))) {
            s.push_str(&format!(
                "{} / {} at {} threads, paired time per step: {} (below 1: {} is faster)\n",
                p.0.strategy.name(),
                first.strategy.name(),
                r.threads,
                p.1.show(4),
                p.0.strategy.name()
            ));
        }
    }
    for p in &r.strategies {
        if p.max_position_difference.is_nan() || p.max_position_difference >= 1e-9 {
            s.push_str(&format!(
                "WARNING: {} at {} threads ended {:.2e} bar lengths away from its 1-thread run: the runs disagree\n",
                p.strategy, r.threads, p.max_position_difference
            ));
        }
    }
    if r.oversubscribed {
        s.push_str(
            "note: oversubscribed (more workers than usable CPUs): these efficiencies are not scaling figures\n",
        );
    }
    if r.debug_build {
        s.push_str("warning: this harness was built with debug assertions; build with --profile o3 for real numbers\n");
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    fn args() -> PairedArgs {
        PairedArgs {
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
        let cases: Vec<(PairedArgs, &str)> = vec![
            (PairedArgs { model: 5, ..args() }, "Models 1-4"),
            (PairedArgs { threads: 1, ..args() }, "use 2 or more"),
            (PairedArgs { blocks: 1, ..args() }, "at least 2"),
            (PairedArgs { block_steps: Some(0), ..args() }, "at least 1"),
            (PairedArgs { warmup: 0, ..args() }, "page faults"),
            (PairedArgs { strategies: vec!["xx".into()], ..args() }, "unknown strategy 'xx'"),
            (PairedArgs { strategies: vec!["serial".into()], ..args() }, "always measured"),
        ];
        for (a, want) in cases {
            let e = measure(&a).unwrap_err().to_string();
            assert!(e.contains(want), "{e}");
        }
    }

    /// A real (tiny) measurement: every configuration timed in every block, the parallel
    /// runs agree with the 1-thread runs, and the efficiencies are the ratios of the times.
    #[test]
    fn paired_blocks_time_every_configuration_and_agree() {
        let r = measure(&args()).unwrap();
        assert_eq!(r.serial_s_per_step.len(), 3);
        assert_eq!(r.strategies.len(), 2);
        for p in &r.strategies {
            assert_eq!(p.t1_s_per_step.len(), 3);
            assert_eq!(p.tt_s_per_step.len(), 3);
            assert_eq!(p.block_imbalance.len(), 3);
            assert!(p.block_imbalance.iter().all(|&i| i >= 1.0), "{:?}", p.block_imbalance);
            for b in 0..3 {
                let e = p.t1_s_per_step[b] / (2.0 * p.tt_s_per_step[b]);
                assert!((p.block_efficiency[b] - e).abs() < 1e-15);
            }
            assert!(p.efficiency.lo <= p.efficiency.value && p.efficiency.value <= p.efficiency.hi);
            assert!(p.max_position_difference < 1e-12, "{}", p.max_position_difference);
        }
        let t = table(&r);
        assert!(t.contains("efficiency, paired") && t.contains("dd-balanced / dd at 2 threads"), "{t}");
        assert!(r.strategies[0].tt_vs_first.is_none());
        let v = r.strategies[1].tt_vs_first.as_ref().unwrap();
        let want: Vec<f64> =
            (0..3).map(|b| r.strategies[1].tt_s_per_step[b] / r.strategies[0].tt_s_per_step[b]).collect();
        assert!(v.lo <= v.value && v.value <= v.hi && want.iter().any(|w| (w - v.value).abs() < 1e-12), "{v:?}");
        assert!(!t.contains("WARNING"), "{t}");
    }
}
