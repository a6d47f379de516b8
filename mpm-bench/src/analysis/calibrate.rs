//! `mpm-bench calibrate`'s verdicts: the regression gate measures itself on the host that
//! runs it. The campaigns are run by [`crate::campaign::measure::calibrate`]; this module
//! compares them ([`judge`]) and reports ([`table`], [`Calibration`]).
//!
//! A gate that fails on noise is switched off; one that passes a 20 % loss is useless; and
//! neither figure can be known without measuring it where the gate runs. `calibrate` runs
//! the gate's own campaign (a preset, by default `ci`) several times with the same binary and
//! several times with an injected slowdown of known size (`--inject-slowdown F`: every
//! worker but the first does extra work so that the parallel efficiency drops by `F`; the
//! rows say so and no analysis takes them for results), interleaved in one session so that
//! the host's drift spreads over both kinds. Then it runs `regress` (the same settings a CI
//! job uses: `--tolerance`, `--metrics`) on
//!
//! * every pair of clean campaigns, the earlier as the baseline (A/A: any failure is a false
//!   alarm), and
//! * every clean campaign as the baseline against every injected one (a failure is a
//!   detection),
//!
//! and writes `calibration.json` ([`Calibration`]): the counts of both, the smallest change
//! the gate detects with 90 % power on this host at this budget, the longest gate run (one
//! campaign plus its `regress`), the repetitions and blocks it recommends, and the coverage
//! of the campaigns' intervals on each other (each clean campaign's 95 % interval of a cell
//! against the mean of the other clean campaigns).
//!
//! # How the comparisons are formed, and what that does to the estimates
//!
//! `N` clean campaigns give `N (N - 1) / 2` A/A comparisons (7 give 21) and, with `K`
//! injected ones, `N K` injected comparisons (7 x 3 = 21). They reuse campaigns, so they are
//! not independent: a clean campaign that happened to run slow takes part in `N - 1` A/A
//! comparisons, and its false alarms come in clusters. The counts are therefore unbiased
//! estimates of the per-comparison rates, but their spread is wider than a binomial over the
//! number of comparisons would say: with 7 campaigns the evidence is closer to 7 independent
//! observations than to 21. The smallest detectable change does not rest on the pairs: it
//! comes from the spread of the clean campaigns' cell means (`sd_campaign_log`), which
//! contains whatever drifts from one campaign to the next, and the t quantile of the gate's
//! Holm level over its checks (the cells and their mean); see
//! [`Calibration::min_detectable_change`] (a loss in one cell) and
//! [`Calibration::min_detectable_change_pooled`] (a loss in every cell, which the gate's
//! pooled check finds with half a cell's standard error at four cells).

use super::paired::{student_t_quantile, two_stage};
use super::regress::{self, Metrics, RegressOptions, RegressReport};
use super::results::{load_campaign, Campaign as Loaded};
use super::select::RowFilter;
use super::stats::{CellKey, Stage, StatsOptions};
use crate::campaign::measure::calibrate::{CalibrateOptions, CalibrationCampaign};
use crate::machine::fingerprint;
use crate::machine::topology::Machine;
use crate::util::now_rfc3339;
use anyhow::{bail, Result};
use serde::Serialize;
use std::collections::BTreeMap;
use std::time::Instant;

/// One `regress` of the calibration.
#[derive(Clone, Debug, Serialize)]
pub struct CalibrationComparison {
    /// `aa` (clean against clean) or `injected` (clean baseline, injected current).
    pub kind: &'static str,
    /// Index of the baseline among the campaigns.
    pub baseline: usize,
    /// Index of the current campaign.
    pub current: usize,
    /// `pass`, `fail` or `incomparable`.
    pub verdict: String,
    /// The gate's reason.
    pub reason: String,
    /// Per efficiency check of one cell: `cell stage`, the ratio current / baseline.
    pub efficiency_ratios: BTreeMap<String, f64>,
    /// The pooled efficiency check's ratio (the mean change over the cells, total step).
    pub pooled_ratio: Option<f64>,
    /// Seconds the gate's comparison took.
    pub regress_s: f64,
}

/// What the clean campaigns say about one cell's noise.
#[derive(Clone, Debug, Serialize)]
pub struct CellNoise {
    /// The cell.
    pub cell: String,
    /// Processes per campaign (the smallest).
    pub processes: usize,
    /// Blocks per process (the smallest).
    pub blocks: usize,
    /// Standard deviation of a block's log efficiency within a process (pooled).
    pub sd_block_log: f64,
    /// Standard deviation of a process's mean log efficiency within a campaign (pooled).
    pub sd_process_log: f64,
    /// Standard deviation of a campaign's mean log efficiency: the spread of the clean
    /// campaigns' means, or the processes' spread over their count when that is larger
    /// (what a comparison of two campaigns sees).
    pub sd_campaign_log: f64,
    /// The smallest efficiency loss the gate detects in this cell with 90 % power.
    pub min_detectable_change: f64,
}

/// `calibration.json`.
#[derive(Clone, Debug, Serialize)]
pub struct Calibration {
    /// A/A comparisons made.
    pub aa_comparisons: usize,
    /// Of those, how many the gate failed.
    pub false_alarms: usize,
    /// The injected efficiency loss (fraction).
    pub injected_slowdown: f64,
    /// Comparisons of a clean baseline with an injected campaign.
    pub injected_comparisons: usize,
    /// Of those, how many the gate failed.
    pub detected: usize,
    /// The smallest efficiency loss (fraction) detected with 90 % power in every cell, from
    /// the clean campaigns' spread (the largest of the cells'); `null` with fewer than two
    /// clean campaigns. This is a loss in that one cell only.
    pub min_detectable_change: Option<f64>,
    /// The smallest efficiency loss (fraction) in every cell at once detected with 90 %
    /// power by the pooled check (the mean over the cells), from the same spread; `null`
    /// with fewer than two cells.
    pub min_detectable_change_pooled: Option<f64>,
    /// The longest gate run: one campaign and its `regress` (s).
    pub gate_wall_s: f64,
    /// `false_alarms / aa_comparisons`.
    pub false_alarm_rate: Option<f64>,
    /// `detected / injected_comparisons`.
    pub detection_rate: Option<f64>,
    /// The efficiency loss the injected campaigns showed: `1 -` the median efficiency ratio
    /// of the injected comparisons' checks.
    pub measured_injected_loss: Option<f64>,
    /// Processes (repetitions) per cell with which the gate detects the injected loss (in
    /// every cell) with 90 % power at this noise, by its pooled check; `null` when the drift
    /// between campaigns alone is too large for any count.
    pub recommended_reps: Option<u64>,
    /// Blocks per process past which more blocks buy little (the within-process noise under
    /// a tenth of the process-to-process spread).
    pub recommended_blocks: Option<u64>,
    /// Per cell, the noise behind these figures.
    pub cells: Vec<CellNoise>,
    /// Each clean campaign's 95 % interval of each cell against the mean of the other clean
    /// campaigns: (intervals, covering).
    pub interval_coverage: (usize, usize),
    /// The gate's settings.
    pub tolerance: f64,
    /// The gate's metrics.
    pub metrics: Vec<String>,
    /// The preset.
    pub preset: String,
    /// The campaigns, in the order they ran.
    pub campaigns: Vec<CalibrationCampaign>,
    /// Every comparison.
    pub comparisons: Vec<CalibrationComparison>,
    /// How the comparisons were formed and what that does to the estimates.
    pub method: &'static str,
    /// Machine fingerprint.
    pub machine: String,
    /// When it finished (RFC 3339).
    pub timestamp: String,
    /// The command line.
    pub command_line: String,
}

/// How the comparisons are formed (written into calibration.json).
pub const METHOD: &str = "A/A: every pair of clean campaigns, the earlier as the baseline; injected: every clean \
    campaign as the baseline against every injected one. The campaigns ran interleaved in one session. Pairs reuse \
    campaigns, so the comparisons are not independent: the rates are unbiased per comparison but scatter more than a \
    binomial over the comparisons (about as much as over the campaigns). min_detectable_change (a loss in one cell) and \
    min_detectable_change_pooled (a loss in every cell, found by the gate's mean over the cells) come from the spread \
    of the clean campaigns' cell means, not from the pairs.";

/// Whether the calibration's settings make sense, in words that say what to give instead.
pub fn check_args(a: &CalibrateOptions) -> Result<()> {
    if a.clean < 2 {
        bail!("--clean {} gives no A/A comparison: use at least 2 (7 give 21 comparisons)", a.clean);
    }
    if !(a.inject_slowdown > 0.0 && a.inject_slowdown < 1.0) {
        bail!(
            "--inject-slowdown {} is not a fraction in (0, 1): e.g. 0.1 for a 10 % efficiency loss",
            a.inject_slowdown
        );
    }
    if !(a.tolerance >= 0.0 && a.tolerance < 1.0) {
        bail!("--tolerance {} is out of range: give a fraction such as 0.05", a.tolerance);
    }
    Metrics::parse(&a.metrics)?;
    Ok(())
}

/// The gate's comparison of two loaded campaigns, with the calibration's settings; the
/// seconds it took (reading both campaigns, as a CI job's `regress` would, plus the
/// comparison: `load_s` is the reading's share, measured once per campaign).
fn gate(a: &CalibrateOptions, baseline: &Loaded, current: &Loaded, load_s: f64) -> Result<(RegressReport, f64)> {
    let t0 = Instant::now();
    let args = RegressOptions {
        tolerance: a.tolerance,
        metrics: a.metrics.clone(),
        ..RegressOptions::new(&baseline.dir, &current.dir)
    };
    let r = regress::compare_campaigns(&args, baseline, current)?;
    Ok((r, load_s + t0.elapsed().as_secs_f64()))
}

/// The gate's comparisons of the calibration's `campaigns` (run on `machine` by
/// [`crate::campaign::measure::calibrate::run_campaigns`]): every A/A pair, every clean
/// campaign against every injected one, the clean campaigns' noise, and the summary.
pub fn judge(a: &CalibrateOptions, machine: &Machine, campaigns: Vec<CalibrationCampaign>) -> Result<Calibration> {
    let clean: Vec<usize> = (0..campaigns.len()).filter(|&i| campaigns[i].kind == "clean").collect();
    let inj: Vec<usize> = (0..campaigns.len()).filter(|&i| campaigns[i].kind == "injected").collect();
    if clean.len() < 2 {
        bail!("only {} clean campaign(s) fit the budget: no A/A comparison; give a larger --budget", clean.len());
    }
    let mut comparisons = Vec::new();
    let pairs = clean
        .iter()
        .enumerate()
        .flat_map(|(x, &i)| clean[x + 1..].iter().map(move |&j| ("aa", i, j)))
        .chain(clean.iter().flat_map(|&i| inj.iter().map(move |&j| ("injected", i, j))));
    let mut gate_wall: f64 = 0.0;
    // Each campaign is read once (with the rows regress keeps) and its rows left out (noisy,
    // ...) said once, not at every comparison.
    let filter = RowFilter::analysis(false).with_injected(true);
    let mut loaded = Vec::new();
    for c in &campaigns {
        let t0 = Instant::now();
        let l = load_campaign(&c.dir, &filter)?;
        if !a.quiet {
            l.note_left_out("regress");
        }
        loaded.push((l, t0.elapsed().as_secs_f64()));
    }
    for (kind, b, c) in pairs.collect::<Vec<_>>() {
        let (r, secs) = gate(a, &loaded[b].0, &loaded[c].0, loaded[b].1 + loaded[c].1)?;
        gate_wall = gate_wall.max(campaigns[c].wall_s + secs);
        comparisons.push(CalibrationComparison {
            kind,
            baseline: b,
            current: c,
            efficiency_ratios: r
                .checks
                .iter()
                .filter(|x| x.metric == "efficiency" && x.cell.key().is_some())
                .map(|x| (format!("{} {}", x.cell, x.stage.name()), x.ratio.value))
                .collect(),
            pooled_ratio: r
                .checks
                .iter()
                .find(|x| x.metric == "efficiency" && x.cell.key().is_none() && x.stage == Stage::Total)
                .map(|x| x.ratio.value),
            verdict: r.verdict,
            reason: r.reason,
            regress_s: secs,
        });
    }
    let noise = cell_noise(a, &campaigns, &clean)?;
    Ok(summarise(a, machine, campaigns, comparisons, noise, gate_wall))
}

/// Per cell: the clean campaigns' processes' and blocks' spread, and the interval coverage.
struct Noise {
    cells: Vec<CellNoise>,
    coverage: (usize, usize),
    /// Per cell, the pooled process SD and the campaign SD (for the recommendations).
    parts: Vec<(f64, f64, f64, usize, usize)>,
    /// Gated efficiency checks per comparison (Holm's family: the cells and the pooled check).
    checks: usize,
    /// The smallest loss in every cell the pooled check detects with 90 % power.
    pooled_mdc: Option<f64>,
}

/// The pooled standard deviation of groups of values (`None` without any degree of freedom).
fn pooled_sd(groups: &[Vec<f64>]) -> Option<f64> {
    let (mut ss, mut df) = (0.0, 0usize);
    for g in groups.iter().filter(|g| g.len() > 1) {
        let m = g.iter().sum::<f64>() / g.len() as f64;
        ss += g.iter().map(|v| (v - m).powi(2)).sum::<f64>();
        df += g.len() - 1;
    }
    (df > 0).then(|| (ss / df as f64).sqrt())
}

fn cell_noise(a: &CalibrateOptions, campaigns: &[CalibrationCampaign], clean: &[usize]) -> Result<Noise> {
    let filter = RowFilter::analysis(false);
    let analyses = clean
        .iter()
        .map(|&i| Ok(load_campaign(&campaigns[i].dir, &filter)?.analyse(None)))
        .collect::<Result<Vec<_>>>()?;
    let keys: Vec<CellKey> = analyses[0]
        .cells
        .iter()
        .filter(|(k, c)| k.threads > 1 && !c.paired.is_empty() && !c.oversubscribed)
        .map(|(k, _)| k.clone())
        .collect();
    let z90 = student_t_quantile(0.9, 1e9);
    let alpha = (1.0 - StatsOptions::default().confidence) / 2.0;
    // The cells' checks and, with two or more cells, the pooled check.
    let checks = (keys.len() + usize::from(keys.len() >= 2)).max(1);
    let tol_log = -(1.0 - a.tolerance).ln();
    let (mut cells, mut parts) = (Vec::new(), Vec::new());
    let mut coverage = (0, 0);
    for key in &keys {
        let per: Vec<&crate::analysis::stats::Cell> = analyses.iter().filter_map(|an| an.cells.get(key)).collect();
        if per.len() < 2 {
            continue;
        }
        let blocks: Vec<Vec<f64>> =
            per.iter().flat_map(|c| c.paired.iter().map(|p| p.ratios.iter().map(|r| r.ln()).collect())).collect();
        let processes: Vec<Vec<f64>> = per.iter().map(|c| c.paired_logs(Stage::Total)).collect();
        let means: Vec<f64> = processes.iter().map(|p| p.iter().sum::<f64>() / p.len() as f64).collect();
        let (Some(sd_block), Some(sd_process), Some(sd_means)) =
            (pooled_sd(&blocks), pooled_sd(&processes), pooled_sd(std::slice::from_ref(&means)))
        else {
            continue;
        };
        let m = processes.iter().map(Vec::len).min().unwrap_or(0);
        // A campaign mean varies at least as its processes say (a few campaigns can show
        // less by chance), more when something drifts from one campaign to the next.
        let sd_campaign = sd_means.max(sd_process / (m.max(1) as f64).sqrt());
        let n = per.iter().flat_map(|c| c.paired.iter().map(|p| p.ratios.len())).min().unwrap_or(0);
        // A comparison of two campaigns: the difference of two campaign means. The gate's
        // first Holm step tests at alpha / checks with about 2 (m - 1) degrees of freedom.
        let se = std::f64::consts::SQRT_2 * sd_campaign;
        let t = student_t_quantile(1.0 - alpha / checks as f64, (2 * m).saturating_sub(2).max(1) as f64);
        let delta = tol_log.max(t * se) + z90 * se;
        cells.push(CellNoise {
            cell: key.to_string(),
            processes: m,
            blocks: n,
            sd_block_log: sd_block,
            sd_process_log: sd_process,
            sd_campaign_log: sd_campaign,
            min_detectable_change: 1.0 - (-delta).exp(),
        });
        parts.push((sd_block, sd_process, sd_campaign, m, n));
        // Each campaign's interval against the other campaigns' mean.
        for (x, c) in per.iter().enumerate() {
            let samples: Vec<Vec<f64>> = c.paired.iter().map(|p| p.ratios.clone()).collect();
            let others: Vec<f64> = means.iter().enumerate().filter(|&(y, _)| y != x).map(|(_, v)| *v).collect();
            let target = (others.iter().sum::<f64>() / others.len() as f64).exp();
            if let Some(iv) = two_stage(&samples, StatsOptions::default().confidence) {
                coverage.0 += 1;
                coverage.1 += usize::from(iv.estimate.lo <= target && target <= iv.estimate.hi);
            }
        }
    }
    // The pooled check: the mean of the cells' differences, variance sum(2 sd_k^2) / K^2.
    let pooled_mdc = (parts.len() >= 2).then(|| {
        let k = parts.len() as f64;
        let se = (parts.iter().map(|p| 2.0 * p.2 * p.2).sum::<f64>()).sqrt() / k;
        let m = parts.iter().map(|p| p.3).min().unwrap_or(2);
        let t = student_t_quantile(1.0 - alpha / checks as f64, (k as usize * (2 * m).saturating_sub(2)).max(1) as f64);
        1.0 - (-(tol_log.max(t * se) + z90 * se)).exp()
    });
    Ok(Noise { cells, coverage, parts, checks, pooled_mdc })
}

/// The figures of calibration.json from the campaigns, comparisons and noise.
fn summarise(
    a: &CalibrateOptions,
    machine: &Machine,
    campaigns: Vec<CalibrationCampaign>,
    comparisons: Vec<CalibrationComparison>,
    noise: Noise,
    gate_wall_s: f64,
) -> Calibration {
    let count = |kind: &str, fail: bool| {
        comparisons.iter().filter(|c| c.kind == kind && (!fail || c.verdict == "fail")).count()
    };
    let (aa, alarms, inj, detected) =
        (count("aa", false), count("aa", true), count("injected", false), count("injected", true));
    let rate = |x: usize, n: usize| (n > 0).then(|| x as f64 / n as f64);
    let mut inj_ratios: Vec<f64> = comparisons
        .iter()
        .filter(|c| c.kind == "injected")
        .flat_map(|c| c.efficiency_ratios.values().copied())
        .collect();
    inj_ratios.sort_by(f64::total_cmp);
    let measured_injected_loss = (!inj_ratios.is_empty()).then(|| 1.0 - crate::util::median(&inj_ratios));
    let (recommended_reps, recommended_blocks) = recommend(a, &noise);
    Calibration {
        aa_comparisons: aa,
        false_alarms: alarms,
        injected_slowdown: a.inject_slowdown,
        injected_comparisons: inj,
        detected,
        min_detectable_change: noise.cells.iter().map(|c| c.min_detectable_change).reduce(f64::max),
        min_detectable_change_pooled: noise.pooled_mdc,
        gate_wall_s,
        false_alarm_rate: rate(alarms, aa),
        detection_rate: rate(detected, inj),
        measured_injected_loss,
        recommended_reps,
        recommended_blocks,
        cells: noise.cells,
        interval_coverage: noise.coverage,
        tolerance: a.tolerance,
        metrics: a.metrics.clone(),
        preset: a.preset.clone(),
        campaigns,
        comparisons,
        method: METHOD,
        machine: fingerprint::fingerprint(machine),
        timestamp: now_rfc3339(),
        command_line: std::env::args().collect::<Vec<_>>().join(" "),
    }
}

/// The repetitions for 90 % power at the injected size and the blocks past which more buy
/// little. A campaign mean's variance is modelled per cell as `s_d^2 + s_p^2 / m`: the
/// process spread `s_p` over `m` processes and a drift `s_d` between campaigns that more
/// processes cannot average away (the part of the campaign spread the processes do not
/// explain). The injected loss hits every cell, so the repetitions are those with which the
/// gate's pooled check (the mean over the cells, variance `sum_k 2 var_k / K^2`) detects it;
/// with one cell, that cell's check.
fn recommend(a: &CalibrateOptions, noise: &Noise) -> (Option<u64>, Option<u64>) {
    let target = -(1.0 - a.inject_slowdown).ln();
    let tol_log = -(1.0 - a.tolerance).ln();
    let alpha = (1.0 - StatsOptions::default().confidence) / 2.0;
    let z = |p: f64| student_t_quantile(p, 1e9);
    let (za, zb) = (z(1.0 - alpha / noise.checks as f64), z(0.9));
    let k = noise.parts.len() as f64;
    let reps = (2..=200u64).find(|&r| {
        let var: f64 = noise
            .parts
            .iter()
            .map(|&(_, sd_process, sd_campaign, m, _)| {
                let drift = (sd_campaign.powi(2) - sd_process.powi(2) / m.max(1) as f64).max(0.0);
                2.0 * (drift + sd_process.powi(2) / r as f64)
            })
            .sum();
        let se = var.sqrt() / k;
        // Detected when the loss beats the tolerance and the test: target >= max(tol, za se) + zb se.
        tol_log.max(za * se) + zb * se <= target
    });
    let mut blocks: Option<u64> = Some(2);
    for &(sd_block, sd_process, _, _, n) in &noise.parts {
        let between = (sd_process.powi(2) - sd_block.powi(2) / n.max(1) as f64).max(1e-12);
        let b = (sd_block.powi(2) / (0.1 * between)).ceil().clamp(2.0, 50.0) as u64;
        blocks = blocks.map(|x| x.max(b));
    }
    let found = !noise.parts.is_empty();
    (reps.filter(|_| found), blocks.filter(|_| found))
}

/// The result for people.
pub fn table(c: &Calibration) -> String {
    use std::fmt::Write as _;
    let mut s = String::new();
    let pct = |x: Option<f64>| x.map_or("-".into(), |v| format!("{:.1} %", 100.0 * v));
    let _ = writeln!(
        s,
        "calibration of the gate (preset {}, tolerance {:.1} %, metrics {}) on machine {}:",
        c.preset,
        100.0 * c.tolerance,
        c.metrics.join(","),
        c.machine
    );
    let _ = writeln!(
        s,
        "  A/A: {} false alarm(s) in {} comparisons ({})",
        c.false_alarms,
        c.aa_comparisons,
        pct(c.false_alarm_rate)
    );
    let _ = writeln!(
        s,
        "  injected {:.0} % efficiency loss: detected in {} of {} comparisons ({}); the injected campaigns measured a loss of {}",
        100.0 * c.injected_slowdown,
        c.detected,
        c.injected_comparisons,
        pct(c.detection_rate),
        pct(c.measured_injected_loss)
    );
    let _ = writeln!(
        s,
        "  smallest loss detected with 90 % power: in any one cell {}; in every cell at once (the pooled check) {}",
        pct(c.min_detectable_change),
        pct(c.min_detectable_change_pooled)
    );
    let _ = writeln!(s, "  longest gate run (campaign + regress): {:.0} s", c.gate_wall_s);
    let _ = writeln!(
        s,
        "  intervals of one campaign covering the other campaigns' mean: {} of {}",
        c.interval_coverage.1, c.interval_coverage.0
    );
    let blocks = c.recommended_blocks.map_or("-".into(), |b| b.to_string());
    let _ = match c.recommended_reps {
        Some(r) => writeln!(s, "  recommended: {r} processes per cell, {blocks} blocks per process"),
        None => writeln!(
            s,
            "  recommended: {blocks} blocks per process; no number of processes per cell detects the injected \
             loss with 90 % power (the drift between campaigns alone is too large: gate on a larger loss, or \
             compare campaigns run interleaved)"
        ),
    };
    for n in &c.cells {
        let _ = writeln!(
            s,
            "  {:<18} {} processes x {} blocks: sd (log) block {:.3}, process {:.3}, campaign {:.3}; detects {}",
            n.cell,
            n.processes,
            n.blocks,
            n.sd_block_log,
            n.sd_process_log,
            n.sd_campaign_log,
            pct(Some(n.min_detectable_change))
        );
    }
    let _ = writeln!(s, "  how: {}", c.method);
    s
}
