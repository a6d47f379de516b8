//! Statistics of a campaign: medians over repetitions with bootstrap confidence intervals,
//! speedup and parallel efficiency (paper Eqs. 19-20).
//!
//! # What is measured
//!
//! A *cell* is one configuration: (model, strategy, optimisation level, threads). Its
//! repetitions are the rows with status `ok` (skipped, failed and invalid rows are not
//! measurements: they make the cell's point absent, never zero). For each cell and each
//! [`Stage`] the time per step of every repetition is:
//!
//! * [`Stage::Total`]: `steady_s_per_step` (wall time per step with the warm-up steps
//!   excluded) when the row has it, else `wall_s / steps`;
//! * [`Stage::Grid`]: `grid_stage_s / steps` (the paper's grid-node stage, Eqs. 1-6);
//! * [`Stage::Particle`]: `particle_stage_s / steps` (the particle stage, Eqs. 7-15).
//!
//! The stage times include the warm-up steps (the solver sums them over every step); the
//! ratios below compare like with like, so this does not bias a speedup.
//!
//! # Estimates
//!
//! * time `T_n`: the median over repetitions;
//! * speedup `s = T_1 / T_n` (Eq. 19) and efficiency `e = s / n` (Eq. 20): ratios of the
//!   medians. `T_1` is the same strategy with one thread; when a campaign has no such cell
//!   but has a `serial` run of the model, that is the base instead (the [`Base`] says which).
//!   The absolute `T_1` is kept next to every speedup.
//!
//! Every estimate carries a percentile-bootstrap confidence interval (default 2000
//! resamples, 95 %): each resample draws every sample involved (numerator and denominator
//! independently) with replacement, takes the medians and forms the statistic; the interval
//! is the (2.5 %, 97.5 %) percentiles of the resampled statistics, widened if needed to
//! contain the point estimate. The generator is a SplitMix64 seeded from a fixed seed and
//! the cell's name, so the same CSV always gives the same intervals, whatever the order of
//! its rows. With a single repetition there is nothing to resample: the interval is the
//! point itself and [`Estimate::degenerate`] says so. Print such estimates as points, not as
//! intervals; the analysis commands do.
//!
//! A point is *oversubscribed* when any of its repetitions ran more threads than usable
//! cores: its time is time sharing, not scaling, and the figures draw it hollow.
//!
//! # Two designs
//!
//! Every point says which [`Design`] its speedup and efficiency come from. *Separate*: the
//! medians of separate processes of one and of `n` threads, as above. *Paired*: the cell's
//! rows are paired runs ([`Row::is_paired`]): each process timed its `n`-thread solver and a
//! one-thread solver of the same strategy in alternating blocks, and the efficiency is
//! [`super::paired::two_stage`]'s over the processes (the mean log efficiency of each
//! process, a Student-t interval over processes); the grid-node and particle stages the same
//! from each process's stage seconds; speedup `= n x efficiency`; `T_1` the reference's time
//! per step (median over processes, bootstrap interval). A paired cell measured by one
//! process only has its blocks' interval, which does not cover the spread between processes:
//! [`Point::within_process_only`], and the claims call it indicative (one repetition).

pub use super::estimate::{compare, Compare, Estimate, SINGLE_REP_MARGIN};
use crate::campaign::store::record::{Row, Status};
use crate::util::{median, SplitMix64};
use anyhow::{bail, Result};
use mpm_core::Strategy;
use serde::Serialize;
use std::collections::{BTreeMap, BTreeSet};
use std::fmt;

/// Which design a point's speedup and efficiency come from (see the module docs).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Design {
    /// Medians of separate processes of one and of `n` threads.
    #[default]
    Separate,
    /// One-thread and `n`-thread solvers in the same processes, alternating blocks; the
    /// interval over processes.
    Paired,
    /// Two builds' processes of the same cell run back to back in pairs, in ABBA order
    /// (`mpm-bench ab`); the interval over the pairs' log ratios.
    Interleaved,
}

impl Design {
    /// `separate` or `paired`.
    pub fn name(self) -> &'static str {
        match self {
            Design::Separate => "separate",
            Design::Paired => "paired",
            Design::Interleaved => "interleaved",
        }
    }
}

/// One process of a paired cell (a paired row).
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct PairedProcess {
    /// Its blocks' efficiencies `t1 / (n tT)`.
    pub ratios: Vec<f64>,
    /// The one-thread reference's median seconds per step.
    pub t1: f64,
    /// The grid-node and particle stages' efficiencies over its blocks, `t1 / (n tT)` of the
    /// stage seconds (rows without them: `None`).
    pub stages: [Option<f64>; 2],
}

impl PairedProcess {
    /// The process of a paired row (`None` when the row is not one).
    pub fn of(r: &Row) -> Option<Self> {
        if !r.is_paired() {
            return None;
        }
        let (p, timing) = (r.paired()?, &r.measured.as_ref()?.timing);
        let n = r.threads() as f64;
        let ratios = p.t1_s_per_step.iter().zip(&p.tt_s_per_step).map(|(a, b)| a / (n * b)).collect();
        let stage = |t1: Option<f64>, tt: Option<f64>| {
            t1.zip(tt).map(|(a, b)| a / (n * b)).filter(|e| e.is_finite() && *e > 0.0)
        };
        Some(Self {
            ratios,
            t1: median(&p.t1_s_per_step),
            stages: [
                stage(p.reference_grid_stage_s, timing.steady_grid_stage_s),
                stage(p.reference_particle_stage_s, timing.steady_particle_stage_s),
            ],
        })
    }

    /// The process's mean log efficiency of `stage` (the blocks' for the total).
    pub fn log_mean(&self, stage: Stage) -> Option<f64> {
        match stage {
            Stage::Total => super::paired::process_log_mean(&self.ratios),
            Stage::Grid => self.stages[0].map(f64::ln),
            Stage::Particle => self.stages[1].map(f64::ln),
        }
    }

    /// The values [`super::paired::two_stage`] takes for `stage`: the blocks for the total,
    /// the process's one stage efficiency otherwise.
    fn samples(&self, stage: Stage) -> Vec<f64> {
        match stage {
            Stage::Total => self.ratios.clone(),
            Stage::Grid => self.stages[0].into_iter().collect(),
            Stage::Particle => self.stages[1].into_iter().collect(),
        }
    }
}

/// Which time of a step.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Stage {
    /// The whole step (the paper's "total computation").
    Total,
    /// The grid-node stage (scatter, assembly, nodal update).
    Grid,
    /// The particle stage (gather, re-map, stress update).
    Particle,
}

impl Stage {
    /// The three stages in the paper's panel order (a), (b), (c).
    pub const ALL: [Stage; 3] = [Stage::Total, Stage::Grid, Stage::Particle];

    /// Short name: `total`, `grid`, `particle`.
    pub fn name(self) -> &'static str {
        match self {
            Stage::Total => "total",
            Stage::Grid => "grid",
            Stage::Particle => "particle",
        }
    }

    /// The paper's panel title.
    pub fn title(self) -> &'static str {
        match self {
            Stage::Total => "(a) Total computation",
            Stage::Grid => "(b) Grid-node stage",
            Stage::Particle => "(c) Particle stage",
        }
    }

    /// Parse `total`, `grid` or `particle`.
    pub fn parse(s: &str) -> Result<Self> {
        match s.trim().to_ascii_lowercase().as_str() {
            "total" => Ok(Stage::Total),
            "grid" | "grid-node" => Ok(Stage::Grid),
            "particle" => Ok(Stage::Particle),
            other => bail!("unknown stage '{other}': use total, grid or particle"),
        }
    }

    /// This stage's steady-state time per step of one row (seconds, warm-up steps left
    /// out), if the row measured it: rows written before CSV schema 6 have the whole run's
    /// stage times only, and give none for the two stages.
    pub fn time_per_step(self, row: &Row) -> Option<f64> {
        let f = row.measured.as_ref()?;
        let steady = Some(f.progress.steady_steps).filter(|&s| s > 0).map(|s| s as f64);
        let t = match self {
            Stage::Total => f.timing.steady_s_per_step?,
            Stage::Grid => f.timing.steady_grid_stage_s? / steady?,
            Stage::Particle => f.timing.steady_particle_stage_s? / steady?,
        };
        (t.is_finite() && t > 0.0).then_some(t)
    }
}

impl fmt::Display for Stage {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

/// Bootstrap settings.
#[derive(Clone, Debug, PartialEq)]
pub struct StatsOptions {
    /// Bootstrap resamples (default 2000).
    pub resamples: usize,
    /// Confidence level of the intervals (default 0.95).
    pub confidence: f64,
    /// Base seed of the generator (default fixed, so results are reproducible).
    pub seed: u64,
}

impl Default for StatsOptions {
    fn default() -> Self {
        Self { resamples: 2000, confidence: 0.95, seed: 0x5eed_1920 }
    }
}

/// FNV-1a of a string (stable seed per cell name).
fn fnv(s: &str) -> u64 {
    s.bytes().fold(0xcbf2_9ce4_8422_2325u64, |h, b| (h ^ b as u64).wrapping_mul(0x0100_0000_01b3))
}

/// Linear-interpolated quantile of a sorted slice.
fn quantile(sorted: &[f64], q: f64) -> f64 {
    let pos = q.clamp(0.0, 1.0) * (sorted.len() - 1) as f64;
    let (i, f) = (pos.floor() as usize, pos.fract());
    if i + 1 < sorted.len() {
        sorted[i] * (1.0 - f) + sorted[i + 1] * f
    } else {
        sorted[i]
    }
}

/// Percentile bootstrap of `stat(medians of samples)`: every sample is resampled with
/// replacement independently; `label` seeds the generator (with `opts.seed`).
pub fn bootstrap(samples: &[&[f64]], stat: &dyn Fn(&[f64]) -> f64, opts: &StatsOptions, label: &str) -> Estimate {
    bootstrap_test(samples, stat, opts, label, 1.0).0
}

/// One-sided bootstrap p-values of a statistic against a null value: the fractions of the
/// bootstrap replicates at or below it and at or above it. `at_most` is the p-value of "the
/// statistic exceeds the null", `at_least` of "it is below the null" (resolution
/// `1 / resamples`).
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct Tails {
    /// Fraction of replicates `<= null`.
    pub at_most: f64,
    /// Fraction of replicates `>= null`.
    pub at_least: f64,
}

/// [`bootstrap`], plus the [`Tails`] of the replicates around `null` (`None` when there is
/// no resampling: single repetitions, or no finite replicate).
pub fn bootstrap_test(
    samples: &[&[f64]],
    stat: &dyn Fn(&[f64]) -> f64,
    opts: &StatsOptions,
    label: &str,
    null: f64,
) -> (Estimate, Option<Tails>) {
    let reps = samples.iter().map(|s| s.len()).min().unwrap_or(0);
    let medians: Vec<f64> = samples.iter().map(|s| median(s)).collect();
    let value = stat(&medians);
    if reps == 0 || samples.iter().all(|s| s.len() < 2) || opts.resamples == 0 {
        return (Estimate::point(value, reps), None);
    }
    let mut rng = SplitMix64(opts.seed ^ fnv(label));
    let mut out = Vec::with_capacity(opts.resamples);
    let mut buf = Vec::new();
    let mut meds = vec![0.0; samples.len()];
    for _ in 0..opts.resamples {
        for (k, s) in samples.iter().enumerate() {
            buf.clear();
            buf.extend((0..s.len()).map(|_| s[rng.index(s.len())]));
            meds[k] = median(&buf);
        }
        let v = stat(&meds);
        if v.is_finite() {
            out.push(v);
        }
    }
    if out.is_empty() {
        return (Estimate::point(value, reps), None);
    }
    out.sort_by(f64::total_cmp);
    let alpha = (1.0 - opts.confidence).clamp(0.0, 1.0) / 2.0;
    let lo = quantile(&out, alpha).min(value);
    let hi = quantile(&out, 1.0 - alpha).max(value);
    let n = out.len() as f64;
    let tails = Tails {
        at_most: out.iter().filter(|&&v| v <= null).count() as f64 / n,
        at_least: out.iter().filter(|&&v| v >= null).count() as f64 / n,
    };
    (Estimate { value, lo, hi, reps }, Some(tails))
}

/// Holm's step-down adjustment of p-values (family-wise error control): the adjusted value
/// of the `k`-th smallest of `m` is `max_{j <= k} min(1, (m - j + 1) p_(j))`. Input order is
/// kept.
pub fn holm(p: &[f64]) -> Vec<f64> {
    let m = p.len();
    let mut order: Vec<usize> = (0..m).collect();
    order.sort_by(|&a, &b| p[a].total_cmp(&p[b]));
    let mut out = vec![0.0; m];
    let mut running: f64 = 0.0;
    for (rank, &i) in order.iter().enumerate() {
        running = running.max(((m - rank) as f64 * p[i]).min(1.0));
        out[i] = running;
    }
    out
}

/// One configuration of a campaign.
///
/// Keys order by model, the strategy's short name (`ae`, `dd`, `serial`), optimisation
/// level and threads, so every table and list keeps that order.
#[derive(Clone, Debug, PartialEq, Eq, Hash, Serialize)]
pub struct CellKey {
    /// Model number (1-4).
    pub model: u32,
    /// The scatter strategy.
    pub strategy: Strategy,
    /// `o3` or `o0`.
    pub opt_level: String,
    /// Worker threads.
    pub threads: usize,
}

impl CellKey {
    /// Build a key.
    pub fn new(model: u32, strategy: Strategy, opt_level: &str, threads: usize) -> Self {
        Self { model, strategy, opt_level: opt_level.into(), threads }
    }

    fn order(&self) -> (u32, &str, &str, usize) {
        (self.model, self.strategy.name(), &self.opt_level, self.threads)
    }
}

impl Ord for CellKey {
    fn cmp(&self, other: &Self) -> std::cmp::Ordering {
        self.order().cmp(&other.order())
    }
}

impl PartialOrd for CellKey {
    fn partial_cmp(&self, other: &Self) -> Option<std::cmp::Ordering> {
        Some(self.cmp(other))
    }
}

/// A strategy's short name in capitals (`AE`, `DD`, `SERIAL`), as tables, legends and
/// bootstrap labels print it.
pub fn tag(s: Strategy) -> String {
    s.name().to_uppercase()
}

/// The strategies that run on several threads (AE, DD), in [`Strategy::ALL`] order.
pub fn parallel_strategies() -> impl Iterator<Item = Strategy> {
    Strategy::ALL.into_iter().filter(|s| s.is_parallel())
}

impl fmt::Display for CellKey {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "Model{} {} {} {}t", self.model, tag(self.strategy), self.opt_level.to_uppercase(), self.threads)
    }
}

/// How far a speedup may exceed the physical cores a run had before it is flagged: 20 %
/// for superlinear cache effects (a model whose working set fits the caches of T cores and
/// not of one, or DD's smaller blocks). The largest such effect measured in the committed
/// campaigns stays below it (`committed_speedups_stay_within_the_margin` in
/// `tests/analysis.rs` reads them all). Above it the figure is not scaling but a
/// measurement error (a warm-up counted in one run and not the other, a slowed base run)
/// or, on SMT siblings, the second hardware thread's yield, which is not more cores:
/// flagged on the point, in points.csv and in the tables, never drawn as plain data.
pub const SUPERLINEAR_MARGIN: f64 = 1.2;

/// The distinct CPUs a run was pinned to, else its workers.
pub fn cpus_of(r: &Row) -> usize {
    let mut c = r.placement.requested_cpus.clone();
    c.sort_unstable();
    c.dedup();
    if c.is_empty() {
        r.threads()
    } else {
        c.len()
    }
}

/// The physical cores a run had (SMT siblings once: `physical_cores`, since CSV schema
/// 10), else, for older rows, its distinct CPUs ([`cpus_of`]).
pub fn cores_of(r: &Row) -> usize {
    r.placement.physical_cores.filter(|&c| c > 0).unwrap_or_else(|| cpus_of(r))
}

/// The flag of a speedup above [`SUPERLINEAR_MARGIN`] times the `cores` physical cores a
/// run had (on `cpus` hardware threads), if it is.
pub fn superlinear_flag(speedup: f64, cores: usize, cpus: usize) -> Option<String> {
    let cores = cores.max(1);
    (speedup > SUPERLINEAR_MARGIN * cores as f64).then(|| {
        let smt = if cpus > cores {
            format!(" (its {cpus} CPUs are SMT siblings: a sibling shares its core's units)")
        } else {
            String::new()
        };
        format!(
            "speedup {speedup:.2} above the {cores} physical core(s) the run had{smt}: more than the {:.0} % cache \
             effects allow",
            (SUPERLINEAR_MARGIN - 1.0) * 100.0
        )
    })
}

/// The raw measurements of one cell.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct Cell {
    /// Time per step of each `ok` repetition, per stage in [`Stage::ALL`] order (s).
    pub times: [Vec<f64>; 3],
    /// Peak resident memory of each `ok` repetition (bytes).
    pub peak_rss: Vec<f64>,
    /// Any repetition (of any status) ran more threads than usable cores.
    pub oversubscribed: bool,
    /// Measured (`ok`) repetitions taken on a busy host (`host_noisy`).
    pub noisy: usize,
    /// Rows that are not `ok`: status and reason.
    pub not_ok: Vec<(Status, String)>,
    /// The memory guard's largest estimate for this cell (bytes).
    pub mem_estimate: u64,
    /// Particles of the model (from any row).
    pub particles: Option<u64>,
    /// The most physical cores any measured repetition had ([`cores_of`]).
    pub cores: usize,
    /// The most CPUs (hardware threads) any measured repetition had ([`cpus_of`]).
    pub cpus: usize,
    /// Measured repetitions without steady-state stage times (rows before CSV schema 6).
    pub no_steady_stages: usize,
    /// Mean grid nodes over the steps (median over `ok` rows).
    pub mean_nodes: Option<f64>,
    /// The processes of the paired rows among the measured ones (empty: separate design).
    pub paired: Vec<PairedProcess>,
    /// The work counters of each measured row that has them (bytes per sub-stage and
    /// worker): deterministic, so equal between repetitions.
    pub work: Vec<std::collections::BTreeMap<mpm_core::Substage, Vec<u64>>>,
    /// The work bound of each measured row that has one.
    pub work_bound: Vec<f64>,
    /// The largest injected slowdown among the measured rows (a test knob).
    pub injected: Option<f64>,
}

impl Cell {
    /// Times of `stage`.
    pub fn times(&self, stage: Stage) -> &[f64] {
        &self.times[stage as usize]
    }

    /// Whether the cell has at least one measurement.
    pub fn measured(&self) -> bool {
        !self.times[0].is_empty()
    }

    /// Add a row of this cell: its times, peak memory and flags when it is `ok` and timed
    /// (then `true`), else its status and reason.
    fn add(&mut self, r: &Row) -> bool {
        self.oversubscribed |= r.placement.oversubscribed;
        self.mem_estimate = self.mem_estimate.max(r.outcome.mem_estimate_bytes);
        self.particles = self.particles.or(r.measured.as_ref().map(|f| f.size.particles as u64));
        if r.outcome.status != Status::Ok {
            self.not_ok.push((r.outcome.status, r.outcome.reason.clone()));
            return false;
        }
        let Some(total) = Stage::Total.time_per_step(r) else {
            self.not_ok.push((Status::Invalid, "status ok but no time measured".into()));
            return false;
        };
        self.times[0].push(total);
        self.noisy += usize::from(r.host.host_noisy);
        self.cores = self.cores.max(cores_of(r));
        self.cpus = self.cpus.max(cpus_of(r));
        let f = r.measured.as_ref();
        self.no_steady_stages += usize::from(f.and_then(|f| f.timing.steady_grid_stage_s).is_none());
        for (i, st) in [Stage::Grid, Stage::Particle].into_iter().enumerate() {
            if let Some(t) = st.time_per_step(r) {
                self.times[i + 1].push(t);
            }
        }
        if let Some(b) = f.and_then(|f| f.memory.peak_rss_bytes) {
            self.peak_rss.push(b as f64);
        }
        self.paired.extend(PairedProcess::of(r));
        let work = f.and_then(|f| f.work.as_ref());
        if let Some(w) = work.filter(|w| !w.bytes.is_empty()) {
            self.work.push(w.bytes.clone());
        }
        self.work_bound.extend(work.map(|w| w.efficiency_bound));
        if let Some(f) = r.injected() {
            self.injected = Some(self.injected.map_or(f, |g: f64| g.max(f)));
        }
        true
    }

    /// The design of the cell's speedups and efficiencies: paired when its measured rows
    /// are paired runs.
    pub fn design(&self) -> Design {
        if self.paired.is_empty() {
            Design::Separate
        } else {
            Design::Paired
        }
    }

    /// The paired processes' mean log efficiencies of `stage` (one per process that has it).
    pub fn paired_logs(&self, stage: Stage) -> Vec<f64> {
        self.paired.iter().filter_map(|p| p.log_mean(stage)).collect()
    }
}

/// The base case of a speedup.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Base {
    /// Strategy of the one-thread run (the point's own, or serial).
    pub strategy: Strategy,
    /// Its time per step, `T_1` (s).
    pub t1: Estimate,
}

/// One plotted point: a cell and a stage.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Point {
    /// The configuration.
    pub key: CellKey,
    /// The stage.
    pub stage: Stage,
    /// Median time per step `T_n` (s).
    pub time: Estimate,
    /// The one-thread base case, when the campaign has one.
    pub base: Option<Base>,
    /// Speedup `T_1 / T_n` (Eq. 19).
    pub speedup: Option<Estimate>,
    /// Efficiency `speedup / n` (Eq. 20).
    pub efficiency: Option<Estimate>,
    /// More threads than usable cores: not a scaling point.
    pub oversubscribed: bool,
    /// Some repetition of the cell or of its base was measured on a busy host.
    pub noisy: bool,
    /// Why the point is not plain data (a speedup above the cores the run had, beyond
    /// [`SUPERLINEAR_MARGIN`]); empty when it is.
    pub flags: Vec<String>,
    /// Which design the speedup and efficiency come from.
    pub design: Design,
    /// A paired point measured by one process: its interval is that process's blocks' and
    /// does not cover the spread between processes.
    pub within_process_only: bool,
}

impl Point {
    /// A point that is evidence of scaling: more than one thread, not oversubscribed, not
    /// flagged.
    pub fn is_real_parallel(&self) -> bool {
        self.key.threads > 1 && !self.oversubscribed && self.flags.is_empty()
    }
}

/// The pinning policy to analyse among `rows`: `pin`, else the first of close, spread, none,
/// else the first label; with a note when the rows use several.
pub fn choose_pin<'r>(rows: impl Iterator<Item = &'r Row>, pin: Option<&str>) -> (String, Option<String>) {
    let pins: BTreeSet<String> = rows.map(Row::pin_label).collect();
    let chosen = match pin {
        Some(p) => p.to_string(),
        None => ["close", "spread", "none"]
            .iter()
            .find(|p| pins.contains(**p))
            .map(|p| p.to_string())
            .or_else(|| pins.iter().next().map(|p| p.to_string()))
            .unwrap_or_default(),
    };
    let note = (pins.len() > 1).then(|| {
        format!(
            "the rows use {} pinning policies ({}); only '{chosen}' is analysed",
            pins.len(),
            pins.iter().cloned().collect::<Vec<_>>().join(", ")
        )
    });
    (chosen, note)
}

/// Statistics of one campaign's rows.
#[derive(Clone, Debug, Default, Serialize)]
pub struct Analysis {
    /// Raw measurements per cell.
    pub cells: BTreeMap<CellKey, Cell>,
    /// Every measured (cell, stage) with its estimates, sorted by key then stage.
    pub points: Vec<Point>,
    /// Pinning policy of the rows analysed.
    pub pin_policy: String,
    /// Things the reader should know (several pinning policies, a missing base case, ...).
    pub notes: Vec<String>,
    /// Machine fingerprints found in the rows.
    pub machine_ids: Vec<String>,
}

impl Analysis {
    /// Analyse `rows`. When the rows use several pinning policies, only `pin` (or, if
    /// `None`, the first of close, spread, none, other lists) is analysed, and a note says so.
    pub fn from_rows(rows: &[Row], pin: Option<&str>, opts: &StatsOptions) -> Self {
        let mut an = Analysis::default();
        an.choose_pin(rows, pin);
        an.note_machines(rows);
        let pin = an.pin_policy.clone();
        an.add_rows(rows.iter().filter(|r| r.pin_label() == pin));
        an.estimate_points(opts);
        an
    }

    /// The pinning policy to analyse, with a note when the rows use several.
    fn choose_pin(&mut self, rows: &[Row], pin: Option<&str>) {
        let (chosen, note) = choose_pin(rows.iter(), pin);
        self.notes.extend(note);
        self.pin_policy = chosen;
    }

    /// The machines the rows come from, with a note when there are several.
    fn note_machines(&mut self, rows: &[Row]) {
        let ids: BTreeSet<&str> = rows.iter().map(|r| r.id.machine_id.as_str()).filter(|s| !s.is_empty()).collect();
        self.machine_ids = ids.into_iter().map(str::to_string).collect();
        if self.machine_ids.len() > 1 {
            self.notes.push(format!(
                "rows from {} machines ({}) are mixed in one campaign",
                self.machine_ids.len(),
                self.machine_ids.join(", ")
            ));
        }
    }

    /// Every row into its cell: `ok` rows as measurements, the others with their reason;
    /// each cell's mean node count is the median over its measured rows.
    fn add_rows<'r>(&mut self, rows: impl Iterator<Item = &'r Row>) {
        let mut nodes: BTreeMap<CellKey, Vec<f64>> = BTreeMap::new();
        for r in rows {
            let key = CellKey::new(r.model(), r.strategy(), r.opt().as_str(), r.threads());
            let cell = self.cells.entry(key.clone()).or_default();
            if cell.add(r) {
                if let Some(n) = r.measured.as_ref().map(|f| f.size.mean_nodes) {
                    nodes.entry(key).or_default().push(n);
                }
            }
        }
        for (k, v) in nodes {
            if let Some(c) = self.cells.get_mut(&k) {
                c.mean_nodes = Some(median(&v));
            }
        }
    }

    /// The estimates of every measured (cell, stage), with a note naming the cells without
    /// a one-thread base.
    fn estimate_points(&mut self, opts: &StatsOptions) {
        let mut missing_base = BTreeSet::new();
        let mut points = Vec::new();
        for (key, cell) in &self.cells {
            for stage in Stage::ALL {
                if cell.times(stage).is_empty() {
                    continue;
                }
                let point = self.estimate(key, stage, opts);
                if point.base.is_none() {
                    missing_base.insert(format!("Model{} {} {}", key.model, key.strategy, key.opt_level));
                }
                points.push(point);
            }
        }
        self.points.extend(points);
        let total = |p: &&Point| p.stage == Stage::Total && p.design == Design::Paired;
        let paired = self.points.iter().filter(total).count();
        if paired > 0 {
            self.notes.push(format!(
                "{paired} cell(s) measured in the paired design: their speedups and efficiencies come from the \
                 1-thread and T-thread solvers of the same processes (alternating blocks), with intervals over \
                 processes; the others' from separate runs"
            ));
        }
        let single: Vec<String> =
            self.points.iter().filter(total).filter(|p| p.within_process_only).map(|p| p.key.to_string()).collect();
        if !single.is_empty() {
            self.notes.push(format!(
                "paired cell(s) measured by one process only ({}): their intervals are its blocks' and do not cover \
                 the spread between processes (indicative; run 3 or more repetitions)",
                single.join(", ")
            ));
        }
        let old: usize = self.cells.values().map(|c| c.no_steady_stages).sum();
        if old > 0 {
            self.notes.push(format!(
                "{old} measured row(s) have no steady-state stage times (CSV schema before 6: their stage \
                 seconds include the warm-up): their grid-node and particle stage points are left out"
            ));
        }
        let flagged = self.points.iter().filter(|p| !p.flags.is_empty()).count();
        if flagged > 0 {
            self.notes.push(format!(
                "{flagged} point(s) flagged: a speedup above the cores the run had (more than {:.0} % beyond, more \
                 than cache effects explain); drawn with a cross, listed with the reason in points.csv, never \
                 counted as scaling",
                (SUPERLINEAR_MARGIN - 1.0) * 100.0
            ));
        }
        if !missing_base.is_empty() {
            self.notes.push(format!(
                "no one-thread run (ok) for {}: no speedup there",
                missing_base.into_iter().collect::<Vec<_>>().join(", ")
            ));
        }
    }

    /// The point of a measured (cell, stage): its time and, against the same strategy on
    /// one thread (else the serial run), speedup and efficiency.
    fn estimate(&self, key: &CellKey, stage: Stage, opts: &StatsOptions) -> Point {
        let cell = &self.cells[key];
        let xs = cell.times(stage);
        let label = format!("{key}/{stage}");
        let time = bootstrap(&[xs], &|m| m[0], opts, &label);
        let own = CellKey { threads: 1, ..key.clone() };
        let serial = CellKey { threads: 1, strategy: Strategy::Serial, ..key.clone() };
        let base_key =
            [own, serial].into_iter().find(|k| self.cells.get(k).is_some_and(|c| !c.times(stage).is_empty()));
        let noisy = cell.noisy > 0 || base_key.as_ref().is_some_and(|bk| self.cells[bk].noisy > 0);
        let (base, speedup) = match base_key {
            Some(bk) => {
                let bs = self.cells[&bk].times(stage);
                let t1 = bootstrap(&[bs], &|m| m[0], opts, &format!("{bk}/{stage}"));
                let s = if bk == *key {
                    Estimate::point(1.0, xs.len())
                } else {
                    bootstrap(&[bs, xs], &|m| m[0] / m[1], opts, &format!("{label}/speedup"))
                };
                (Some(Base { strategy: bk.strategy, t1 }), Some(s))
            }
            None => (None, None),
        };
        let mut efficiency = speedup.map(|s| s.scale(1.0 / key.threads as f64));
        let (mut base, mut speedup) = (base, speedup);
        let mut within_process_only = false;
        let paired = (key.threads > 1)
            .then(|| {
                let samples: Vec<Vec<f64>> = cell.paired.iter().map(|p| p.samples(stage)).collect();
                super::paired::two_stage(&samples, opts.confidence)
            })
            .flatten();
        let design = if let Some(iv) = paired {
            let n = key.threads as f64;
            let t1s: Vec<f64> = cell.paired.iter().map(|p| p.t1).collect();
            within_process_only = iv.within_process_only;
            efficiency = Some(iv.estimate);
            speedup = Some(iv.estimate.scale(n));
            base = Some(Base {
                strategy: key.strategy,
                t1: bootstrap(&[&t1s], &|m| m[0], opts, &format!("{label}/paired-t1")),
            });
            Design::Paired
        } else {
            Design::Separate
        };
        let flags = speedup.and_then(|s| superlinear_flag(s.value, cell.cores, cell.cpus)).into_iter().collect();
        Point {
            key: key.clone(),
            stage,
            time,
            base,
            speedup,
            efficiency,
            oversubscribed: cell.oversubscribed,
            noisy,
            flags,
            design,
            within_process_only,
        }
    }

    /// The point of a cell and stage.
    pub fn point(&self, model: u32, strategy: Strategy, opt: &str, threads: usize, stage: Stage) -> Option<&Point> {
        self.points.iter().find(|p| {
            p.stage == stage
                && p.key.model == model
                && p.key.threads == threads
                && p.key.strategy == strategy
                && p.key.opt_level == opt
        })
    }

    /// The points of one line of a figure, by ascending thread count.
    pub fn series(&self, model: u32, strategy: Strategy, opt: &str, stage: Stage) -> Vec<&Point> {
        let mut v: Vec<&Point> = self
            .points
            .iter()
            .filter(|p| {
                p.stage == stage && p.key.model == model && p.key.strategy == strategy && p.key.opt_level == opt
            })
            .collect();
        v.sort_by_key(|p| p.key.threads);
        v
    }

    /// Models present, ascending.
    pub fn models(&self) -> Vec<u32> {
        let s: BTreeSet<u32> = self.cells.keys().map(|k| k.model).collect();
        s.into_iter().collect()
    }

    /// Thread counts present, ascending.
    pub fn thread_counts(&self) -> Vec<usize> {
        let s: BTreeSet<usize> = self.cells.keys().map(|k| k.threads).collect();
        s.into_iter().collect()
    }

    /// Median peak memory of a cell with its interval (bytes).
    pub fn memory(&self, key: &CellKey, opts: &StatsOptions) -> Option<Estimate> {
        let c = self.cells.get(key)?;
        (!c.peak_rss.is_empty()).then(|| bootstrap(&[&c.peak_rss], &|m| m[0], opts, &format!("{key}/rss")))
    }

    /// Cells that have rows but no measurement, with the (first) reason.
    pub fn unmeasured(&self) -> Vec<(&CellKey, &Cell)> {
        self.cells.iter().filter(|(_, c)| !c.measured()).collect()
    }

    /// Whether any plotted point is oversubscribed.
    pub fn any_oversubscribed(&self) -> bool {
        self.points.iter().any(|p| p.oversubscribed)
    }

    /// Largest number of repetitions of any cell.
    pub fn max_reps(&self) -> usize {
        self.cells.values().map(|c| c.times[0].len()).max().unwrap_or(0)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn quantiles_interpolate() {
        assert_eq!(quantile(&[0.0, 10.0], 0.25), 2.5);
    }

    #[test]
    fn single_rep_is_degenerate_and_bootstrap_is_deterministic() {
        let o = StatsOptions::default();
        let e = bootstrap(&[&[2.0]], &|m| m[0], &o, "x");
        assert!(e.degenerate());
        assert_eq!((e.lo, e.value, e.hi), (2.0, 2.0, 2.0));
        let xs = [1.0, 1.1, 0.9, 1.05, 0.95];
        let a = bootstrap(&[&xs], &|m| m[0], &o, "y");
        let b = bootstrap(&[&xs], &|m| m[0], &o, "y");
        assert_eq!(a, b);
        assert!(a.lo <= 1.0 && a.hi >= 1.0 && a.lo < a.hi, "{a:?}");
        assert!(a.lo >= 0.9 && a.hi <= 1.1);
    }

    #[test]
    fn compare_uses_intervals_or_margin() {
        let a = Estimate { value: 1.0, lo: 0.9, hi: 1.1, reps: 3 };
        let b = Estimate { value: 1.3, lo: 1.2, hi: 1.4, reps: 3 };
        assert_eq!(compare(&a, &b), Compare::Less);
        assert_eq!(compare(&b, &a), Compare::Greater);
        assert_eq!(compare(&Estimate::point(1.0, 1), &Estimate::point(1.02, 1)), Compare::Within);
        assert_eq!(compare(&Estimate::point(1.0, 1), &Estimate::point(1.2, 1)), Compare::Less);
    }

    #[test]
    fn holm_adjusts_step_down() {
        let adj = holm(&[0.01, 0.04, 0.03, 0.005]);
        // Sorted 0.005, 0.01, 0.03, 0.04 -> x4, x3, x2, x1 with the running maximum.
        let want = [0.03, 0.06, 0.06, 0.02];
        for (a, w) in adj.iter().zip(want) {
            assert!((a - w).abs() < 1e-12, "{adj:?}");
        }
        assert_eq!(holm(&[0.9, 0.8]), vec![1.0, 1.0]);
        assert!(holm(&[]).is_empty());
    }

    #[test]
    fn bootstrap_tails_count_replicates_around_the_null() {
        let o = StatsOptions::default();
        let (e, t) = bootstrap_test(&[&[2.0, 2.1, 1.9], &[1.0, 1.01, 0.99]], &|m| m[0] / m[1], &o, "t", 1.0);
        let t = t.unwrap();
        assert!(e.lo > 1.0 && t.at_most == 0.0 && t.at_least == 1.0, "{e:?} {t:?}");
        assert!(bootstrap_test(&[&[1.0], &[2.0]], &|m| m[0] / m[1], &o, "t", 1.0).1.is_none());
    }
}
