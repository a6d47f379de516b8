//! The options of the measurements (`bandwidth`, `paired`, `imbalance`, `calibrate`), as
//! clap parses them; each converts into its library options.

use std::path::PathBuf;

/// Measure the memory-bandwidth ceiling (STREAM triad) per thread count and pinning policy.
///
/// Each thread count gets its own pinned rayon pool and freshly first-touched arrays; the
/// best of `--reps` timed passes is the ceiling. Store the JSON with the campaign it
/// belongs to (`--out results/<fingerprint>/<campaign>/bandwidth.json`) so `mpm-bench
/// report` can say what fraction of the ceiling each MPM stage reaches.
#[derive(clap::Args, Debug, Clone)]
pub struct BandwidthArgs {
    /// Thread counts to measure, comma-separated (more than the usable cores is allowed and
    /// flagged oversubscribed).
    #[arg(long, value_delimiter = ',', default_value = "1,2,4,6,8")]
    pub threads: Vec<usize>,
    /// Pinning policy: close, spread, none, or an explicit CPU list such as 0,1 (repeat the
    /// flag to measure several policies).
    #[arg(long = "pin", default_value = "close")]
    pub pin: Vec<String>,
    /// Size of EACH of the three arrays in MiB (0 = automatic: 4 x the total last-level
    /// cache, at least 64 MiB).
    #[arg(long, default_value_t = 0)]
    pub size_mib: u64,
    /// Timed passes per configuration (the best one is the ceiling; STREAM uses 10).
    #[arg(long, default_value_t = 10)]
    pub reps: usize,
    /// Write the result as JSON here (e.g. `results/FINGERPRINT/CAMPAIGN/bandwidth.json`).
    #[arg(long)]
    pub out: Option<PathBuf>,
}

impl From<BandwidthArgs> for mpm_bench::machine::bandwidth::BandwidthOptions {
    fn from(a: BandwidthArgs) -> Self {
        Self { threads: a.threads, pin: a.pin, size_mib: a.size_mib, reps: a.reps, out: a.out }
    }
}

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
    /// Strategies to measure, comma-separated: ae, dd, dd-balanced, colour, atomic. Each
    /// after the first is also compared with the first at `--threads` threads, block by
    /// block (e.g. `dd,dd-balanced`: the cost or gain of balanced cuts).
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

impl From<PairedArgs> for mpm_bench::campaign::measure::paired::PairedOptions {
    fn from(a: PairedArgs) -> Self {
        Self {
            model: a.model,
            strategies: a.strategies,
            threads: a.threads,
            pin: a.pin,
            blocks: a.blocks,
            block_steps: a.block_steps,
            warmup: a.warmup,
            json: a.json,
            quiet: a.quiet,
        }
    }
}

/// Predict the work imbalance of uniform and balanced DD cuts over a run (no timing).
#[derive(clap::Args, Debug, Clone)]
pub struct ImbalanceArgs {
    /// Scenario: taylor (the Taylor bar) or impact (sphere on plate).
    #[arg(long, value_parser = ["taylor", "impact"])]
    pub scenario: String,
    /// Model: Taylor bar 1-4; impact 1-3 = the small model with 2.12, 1.59, 1.06 mm cells,
    /// 4 = the large model.
    #[arg(long, default_value_t = 1)]
    pub model: u32,
    /// Thread counts (one patch per thread; the layouts of `dd`), comma-separated.
    #[arg(long, value_delimiter = ',', default_value = "2,4,6,8")]
    pub threads: Vec<usize>,
    /// Steps to run (default: to the scenario's end time, 40 us for the bar, 30.6 us for
    /// the impact).
    #[arg(long)]
    pub steps: Option<u64>,
    /// Folder for `imbalance-<scenario>-m<model>.{csv,png,svg}`.
    #[arg(long, value_name = "DIR", default_value = "paper-figures")]
    pub out: PathBuf,
}

impl From<ImbalanceArgs> for mpm_bench::campaign::measure::imbalance::ImbalanceOptions {
    fn from(a: ImbalanceArgs) -> Self {
        Self { scenario: a.scenario, model: a.model, threads: a.threads, steps: a.steps, out: a.out }
    }
}

/// Measure the gate's false-alarm rate and detection power on this host.
#[derive(clap::Args, Debug, Clone)]
pub struct CalibrateArgs {
    /// The gate to calibrate: `regress` (whole campaigns against a stored baseline) or `ab`
    /// (sides of one build side by side, process by process, as `mpm-bench ab` runs them;
    /// --injected sides per change: an efficiency loss and a step slowdown).
    #[arg(long, default_value = "regress", value_parser = ["regress", "ab"])]
    pub design: String,
    /// The preset of every gate run: a name (ci, quick, ...) or a TOML file.
    #[arg(long, default_value = "ci")]
    pub preset: String,
    /// Clean campaigns (the same binary, nothing injected); every pair is an A/A comparison.
    #[arg(long, default_value_t = 7)]
    pub clean: usize,
    /// Campaigns with the injected slowdown; each is compared with every clean one.
    #[arg(long, default_value_t = 3)]
    pub injected: usize,
    /// The injected efficiency loss, a fraction (0.1: the T-thread efficiency drops by 10 %).
    #[arg(long, default_value_t = 0.1)]
    pub inject_slowdown: f64,
    /// With --design ab: the injected step slowdown of the time-per-step sides (0.1: every
    /// step takes 1 / 0.9 as long on every worker alike).
    #[arg(long, default_value_t = 0.1)]
    pub inject_step_slowdown: f64,
    /// With --design ab: processes per cell and side (default: the preset's).
    #[arg(long)]
    pub reps: Option<u32>,
    /// With --design ab: the seed of the sides' order.
    #[arg(long)]
    pub seed: Option<u64>,
    /// Stop starting campaigns when the next would likely end after this much time (e.g.
    /// 90m); the comparisons are made with the campaigns done.
    #[arg(long, value_name = "DURATION")]
    pub budget: Option<String>,
    /// The gate's tolerance, as `regress --tolerance`.
    #[arg(long, default_value_t = 0.05)]
    pub tolerance: f64,
    /// The gate's metrics, as `regress --metrics` (default: efficiency,work for `regress`,
    /// as its CI recipe; efficiency,time,work for `ab`).
    #[arg(long, value_delimiter = ',')]
    pub metrics: Option<Vec<String>>,
    /// Root of the results tree: the campaigns go to
    /// <out>/<fingerprint>/calibrate-<preset>-{clean,inject<F>}-<i>/.
    #[arg(long, default_value = "results/local")]
    pub out: PathBuf,
    /// Where to write calibration.json (default: <out>/<fingerprint>/calibrate-<preset>/calibration.json).
    #[arg(long, value_name = "FILE")]
    pub json: Option<PathBuf>,
    /// Do not build the solver; use the existing target/o3/mpm (and target/o0/mpm).
    #[arg(long)]
    pub no_build: bool,
    /// No progress lines.
    #[arg(long, short = 'q')]
    pub quiet: bool,
    /// Use a fake solver (testing the harness itself).
    #[arg(long, hide = true)]
    pub mock: bool,
}

impl From<CalibrateArgs> for mpm_bench::campaign::measure::calibrate::CalibrateOptions {
    fn from(a: CalibrateArgs) -> Self {
        Self {
            preset: a.preset,
            clean: a.clean,
            injected: a.injected,
            inject_slowdown: a.inject_slowdown,
            budget: a.budget,
            tolerance: a.tolerance,
            metrics: a.metrics.unwrap_or_else(|| {
                let m: &[&str] =
                    if a.design == "ab" { &["efficiency", "time", "work"] } else { &["efficiency", "work"] };
                m.iter().map(|s| s.to_string()).collect()
            }),
            out: a.out,
            json: a.json,
            no_build: a.no_build,
            quiet: a.quiet,
            mock: a.mock,
            design_ab: a.design == "ab",
            inject_step_slowdown: a.inject_step_slowdown,
            reps: a.reps,
            seed: a.seed,
        }
    }
}
