//! `mpm-bench regress`: a CI gate on parallel efficiency and time per step.
//!
//! Compares a current campaign to a baseline campaign cell by cell, like with like: the same
//! hardware class (CPU model, sockets, cores, SMT, memory class, ISA levels: another machine
//! id, microcode or kernel compares; another class does not unless `--force`, see
//! [`crate::machine::fingerprint::incomparable`]) and the same (model, strategy, optimisation
//! level, threads) cells, for the stages asked (default: the total step) and the metrics asked
//! (`--metrics`, default all three). For each cell measured in both:
//!
//! * `time`: the ratio `T_current / T_baseline` of the median times per step;
//! * `efficiency` (cells with more than one thread): the ratio `e_current / e_baseline`. In
//!   the separate design each efficiency is `T_1 / (n T_n)` from medians, the ratio with a
//!   percentile-bootstrap interval (every sample resampled independently,
//!   [`super::stats::bootstrap_test`]) and one-sided bootstrap p-values of "worse" and
//!   "better". In the paired design (both campaigns' cells measured by paired runs) it is
//!   Welch's t on the processes' mean log efficiencies ([`super::paired::compare`]): an
//!   interval over processes, which covers the spread between them; with fewer than two
//!   processes a side there is no p-value (the tolerance alone decides, as with single
//!   repetitions). A cell paired in one campaign and not in the other is not compared.
//!   Every check names its design.
//! * `efficiency`, pooled (`mean of K cells`): with two or more gated paired cells, one more
//!   check per stage, the mean over those cells of their changes in mean log efficiency
//!   ([`super::paired::compare_pooled`]). A change of the code that costs every cell a
//!   little moves each by less than its own noise; the mean of K independent cells has half
//!   a cell's standard error at K = 4. On the development VM a 10 % loss was missed in 3 of
//!   21 comparisons by the cells alone, each cell 3-13 % down. The pooled check is one more
//!   member of the Holm family, so the family-wise level holds with it; a loss in one cell
//!   only is still found by that cell's own check.
//! * `work`: the deterministic work counters ([`mpm_core::work`]: bytes per sub-stage and
//!   worker), compared exactly, beside the timing: equal passes; a worker or the total
//!   moving more bytes in any sub-stage (a lost balance, a grown assembly) is a regression on
//!   any host, however noisy, named by sub-stage; less is an improvement. No tolerance, no
//!   p-value: the counts are the same on every run of the same code.
//!
//! The p-values of the gated checks are Holm-adjusted ([`super::stats::holm`]) so that the chance of one false alarm over all cells stays at
//! `(1 - confidence) / 2` = 2.5 % per direction (for a single check this is exactly "the 95 %
//! interval excludes no change"). A check *regresses* when the change is worse than the
//! tolerance (time ratio above `1 + tol`, efficiency ratio below `1 - tol`) **and** its
//! adjusted p-value is below that level; it *improves* likewise in the other direction;
//! otherwise it is *unchanged*. With single repetitions there is no interval and no p-value,
//! so the tolerance alone decides (the verdict says so).
//!
//! A baseline cell that is missing, failed or invalid in the current campaign (or has failed
//! or invalid repetitions there) fails the gate, named, unless `--allow-missing`.
//! Oversubscribed cells (more threads than cores) are time sharing and very noisy: they are
//! compared and listed, but not gated unless `--include-oversubscribed`.
//!
//! Rows with an injected slowdown (`--inject-slowdown`, a test knob) are compared like any
//! other (that is how `mpm-bench calibrate` measures the gate), and the verdict says so.
//!
//! `--work-snapshot FILE` also checks the current campaign's work counters exactly against a
//! committed snapshot ([`super::work_snapshot`]): a cell whose counters differ fails the gate,
//! named with the sub-stage, however the timing went.
//!
//! A first run has no baseline: by default that is an error (exit 2); with
//! `--missing-baseline pass` (a CI job's first run, [`RegressOptions::missing_baseline_passes`])
//! the verdict is `pass`, "no baseline yet; this run becomes it" (exit 0), and the job stores
//! its campaign as the baseline.
//!
//! Exit code: 0 pass, 1 regression (or a missing cell, or work counters off the snapshot), 2
//! error or incomparable (unreadable input, another hardware class without `--force`, no cell
//! in common). The JSON verdict
//! (`--json FILE`, `-` for standard output) is written whenever both campaigns could be
//! read; `--markdown FILE` appends a Markdown summary (for `$GITHUB_STEP_SUMMARY` or a
//! merge-request comment).

use super::results::{load_campaign, Campaign};
use super::select::{configuration_differences, RowFilter};
use super::stats::{bootstrap_test, holm, Analysis, Cell, CellKey, Design, Estimate, Stage, StatsOptions, Tails};
use super::work_snapshot::{work_changes, SnapshotCheck};
use crate::campaign::store::record::Status;
use crate::util::median;
use anyhow::{bail, Context, Result};
use serde::Serialize;
use std::path::{Path, PathBuf};

/// Compare a campaign to a baseline and fail when efficiency or time per step regressed.
///
/// A check fails when it got worse than --tolerance AND the change is beyond the noise
/// (bootstrap p-value, Holm-corrected over all cells). A baseline cell missing, failed or
/// invalid in the current campaign fails too (unless --allow-missing). Exit code 0 = pass,
/// 1 = regression, 2 = error or incomparable (unreadable input, another hardware class
/// without --force, no cell in common). Use in CI with a committed baseline campaign.
#[derive(Debug, Clone)]
pub struct RegressOptions {
    /// Baseline results: a campaign folder (holding runs.csv) or a folder containing
    /// campaigns (then the newest is used).
    pub baseline: PathBuf,
    /// Current results, same forms as --baseline.
    pub current: PathBuf,
    /// Relative change tolerated before a check can fail (0.05 = 5 %).
    pub tolerance: f64,
    /// Compare even when the hardware classes differ (the verdict then compares different
    /// hardware: use with care).
    pub force: bool,
    /// Write the machine-readable verdict here (JSON).
    pub json: Option<PathBuf>,
    /// A missing baseline (no folder, or no campaign in it) passes: "no baseline yet; this
    /// run becomes it" (exit 0). Otherwise it is an error (exit 2).
    pub missing_baseline_passes: bool,
    /// Check the current campaign's work counters exactly against this snapshot file.
    pub work_snapshot: Option<PathBuf>,
    /// Stages to gate, comma-separated: total, grid, particle.
    pub stages: Vec<String>,
    /// Also gate oversubscribed cells (more threads than cores; noisy).
    pub include_oversubscribed: bool,
    /// Pinning policy to compare when a campaign has several (default: close, else the first).
    pub pin: Option<String>,
    /// Keep rows measured on a busy host (host_noisy), left out by default.
    pub include_noisy: bool,
    /// Do not fail when a baseline cell is missing, failed or invalid in the current
    /// campaign (such cells are still listed).
    pub allow_missing: bool,
    /// What to gate, comma-separated: efficiency (parallel efficiency), time (time per
    /// step), work (the work counters, exactly). Time per step follows the host's speed
    /// from one day to the next; a CI gate on a shared runner gates efficiency and work.
    pub metrics: Vec<String>,
    /// Append a Markdown summary of the verdict to FILE (e.g. "$GITHUB_STEP_SUMMARY").
    pub markdown: Option<PathBuf>,
}

impl RegressOptions {
    /// `regress --baseline BASELINE --current CURRENT` with every other option's default.
    pub fn new(baseline: &Path, current: &Path) -> Self {
        Self {
            baseline: baseline.to_path_buf(),
            current: current.to_path_buf(),
            tolerance: 0.05,
            force: false,
            json: None,
            missing_baseline_passes: false,
            work_snapshot: None,
            stages: vec!["total".into()],
            include_oversubscribed: false,
            pin: None,
            include_noisy: false,
            allow_missing: false,
            metrics: vec!["efficiency".into(), "time".into(), "work".into()],
            markdown: None,
        }
    }
}

/// What `--metrics` asked to gate.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Metrics {
    /// Parallel efficiency.
    pub efficiency: bool,
    /// Time per step.
    pub time: bool,
    /// The work counters.
    pub work: bool,
}

impl Metrics {
    /// Every metric.
    pub const ALL: Metrics = Metrics { efficiency: true, time: true, work: true };

    /// Parse `--metrics`.
    pub fn parse(list: &[String]) -> Result<Self> {
        let mut m = Metrics { efficiency: false, time: false, work: false };
        for s in list {
            match s.trim().to_ascii_lowercase().as_str() {
                "efficiency" => m.efficiency = true,
                "time" => m.time = true,
                "work" => m.work = true,
                other => bail!("unknown metric '{other}' in --metrics: use efficiency, time and/or work"),
            }
        }
        if m == (Metrics { efficiency: false, time: false, work: false }) {
            bail!("--metrics is empty: give efficiency, time and/or work");
        }
        Ok(m)
    }
}

/// What one check found.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Outcome {
    /// Worse beyond the tolerance and beyond the noise.
    Regressed,
    /// Better beyond the tolerance and beyond the noise.
    Improved,
    /// Neither.
    Unchanged,
}

/// What a check is about: one cell, or the mean change over several cells.
#[derive(Clone, Debug, PartialEq, Serialize)]
#[serde(untagged)]
pub enum Subject {
    /// One cell (in JSON: the cell's key).
    Cell(CellKey),
    /// The mean change of the paired efficiency over these cells
    /// ([`super::paired::compare_pooled`]; in JSON: `{"pooled": [keys]}`).
    Pooled {
        /// The cells pooled.
        pooled: Vec<CellKey>,
    },
}

impl Subject {
    /// The cell of a one-cell check.
    pub fn key(&self) -> Option<&CellKey> {
        match self {
            Subject::Cell(k) => Some(k),
            Subject::Pooled { .. } => None,
        }
    }
}

impl std::fmt::Display for Subject {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Subject::Cell(k) => write!(f, "{k}"),
            Subject::Pooled { pooled } => write!(f, "mean of {} cells", pooled.len()),
        }
    }
}

/// One metric of one cell (or of the mean over cells).
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Check {
    /// The cell, or the cells pooled.
    pub cell: Subject,
    /// The stage.
    pub stage: Stage,
    /// `time_per_step` or `efficiency`.
    pub metric: &'static str,
    /// Unit of `baseline` and `current`: `s` (time per step) or `1` (efficiency).
    pub unit: &'static str,
    /// Baseline value (median), in `unit`.
    pub baseline: f64,
    /// Current value (median), in `unit`.
    pub current: f64,
    /// Repetitions of the baseline cell.
    pub baseline_reps: usize,
    /// Repetitions of the current cell.
    pub current_reps: usize,
    /// current / baseline, with its interval.
    pub ratio: Estimate,
    /// Relative change in the "worse" direction (positive = worse): `ratio - 1` for time,
    /// `1 - ratio` for efficiency.
    pub worse_by: f64,
    /// One-sided bootstrap p-value of "worse" (`None` with single repetitions).
    pub p_worse: Option<f64>,
    /// One-sided bootstrap p-value of "better".
    pub p_better: Option<f64>,
    /// `p_worse` after Holm's correction over the gated checks.
    pub p_worse_holm: Option<f64>,
    /// `p_better` after Holm's correction over the gated checks.
    pub p_better_holm: Option<f64>,
    /// Which design the values come from (`paired`: over processes; `separate`: medians of
    /// separate runs); time per step is always the runs' own.
    pub design: Design,
    /// Verdict of the check.
    pub outcome: Outcome,
    /// Whether the check counts for the gate (not oversubscribed, or forced in).
    pub gated: bool,
    /// The cell is oversubscribed in either campaign.
    pub oversubscribed: bool,
}

/// The work counters of one cell compared exactly.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct WorkCheck {
    /// The cell.
    pub cell: CellKey,
    /// The baseline's work bound (`W_1 / (T max W_w)`).
    pub baseline_bound: Option<f64>,
    /// The current work bound.
    pub current_bound: Option<f64>,
    /// The baseline's bytes of the busiest worker, over every sub-stage.
    pub baseline_max_worker_bytes: u64,
    /// The current bytes of the busiest worker.
    pub current_max_worker_bytes: u64,
    /// What differs, sub-stage by sub-stage (empty: every count equal).
    pub changes: Vec<String>,
    /// Equal: unchanged; more bytes for a worker or in all: regressed; else improved.
    pub outcome: Outcome,
}

/// A cell measured in both campaigns but not compared, and why.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct NotCompared {
    /// The cell.
    pub cell: String,
    /// The metric.
    pub metric: &'static str,
    /// Why not.
    pub reason: String,
}

/// A baseline cell without a (complete) measurement in the current campaign.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct MissingCell {
    /// The cell, e.g. `Model1 DD O3 2t`.
    pub cell: String,
    /// `missing` (no row), `failed`, `invalid` or `skipped`.
    pub status: String,
    /// Why, from the current campaign's rows.
    pub reason: String,
    /// Whether it counts for the gate (not oversubscribed, or forced in).
    pub gated: bool,
}

/// One side of the comparison.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Side {
    /// Campaign folder.
    pub dir: String,
    /// Campaign id.
    pub campaign: String,
    /// Machine fingerprint (the exact host).
    pub fingerprint: String,
    /// Hardware class id (what decides comparability; `null` for a manifest older than
    /// the class).
    pub hardware_class: Option<String>,
}

/// The machine-readable verdict.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct RegressReport {
    /// `pass`, `fail` or `incomparable`.
    pub verdict: String,
    /// Why, in one sentence.
    pub reason: String,
    /// Tolerance used (fraction).
    pub tolerance: f64,
    /// Family-wise significance level per direction (Holm), fraction.
    pub alpha: f64,
    /// Baseline.
    pub baseline: Side,
    /// Current.
    pub current: Side,
    /// The hardware classes differ and `--force` was given.
    pub forced: bool,
    /// There was no baseline and `--missing-baseline pass` was given: this run becomes it.
    pub no_baseline: bool,
    /// The current campaign's work counters against the committed snapshot
    /// (`--work-snapshot`); differing counters fail the gate.
    pub work_snapshot: Option<SnapshotCheck>,
    /// Every sample had a single repetition: the tolerance alone decided.
    pub single_repetition: bool,
    /// Number of checks that count for the gate.
    pub gated_checks: usize,
    /// Gated checks that regressed.
    pub regressions: Vec<Check>,
    /// Gated checks that improved.
    pub improvements: Vec<Check>,
    /// Every check.
    pub checks: Vec<Check>,
    /// Baseline cells missing, failed, invalid or skipped in the current campaign.
    pub missing_in_current: Vec<MissingCell>,
    /// `--allow-missing` was given: missing cells do not fail the gate.
    pub allow_missing: bool,
    /// The metrics gated (`efficiency`, `time`, `work`).
    pub metrics: Vec<&'static str>,
    /// The work counters of every cell compared (with `work` among the metrics).
    pub work_checks: Vec<WorkCheck>,
    /// Work checks that regressed (they fail the gate).
    pub work_regressions: Vec<WorkCheck>,
    /// Cells and metrics not compared, and why.
    pub not_compared: Vec<NotCompared>,
    /// The largest injected slowdown among the baseline's rows (a test knob), if any.
    pub baseline_injected: Option<f64>,
    /// The largest injected slowdown among the current rows, if any.
    pub current_injected: Option<f64>,
    /// The baseline and the current are the same rows (one campaign given twice): the
    /// comparison tests nothing and its pass says nothing about a change.
    pub same_rows: bool,
}

/// The warning of a comparison of a campaign with itself.
const SAME_ROWS: &str = "warning: the baseline and the current are the same rows (one campaign given twice): the \
                         comparison tests nothing; give the campaign of the change as --current";

impl RegressReport {
    /// Exit code: 0 pass, 1 fail, 2 incomparable.
    pub fn exit_code(&self) -> i32 {
        match self.verdict.as_str() {
            "pass" => 0,
            "fail" => 1,
            _ => 2,
        }
    }

    /// Gated missing cells that fail the gate.
    pub fn failing_missing(&self) -> Vec<&MissingCell> {
        if self.allow_missing {
            return Vec::new();
        }
        self.missing_in_current.iter().filter(|m| m.gated).collect()
    }
}

/// Family-wise significance level per direction for the bootstrap settings.
pub(crate) fn alpha(o: &StatsOptions) -> f64 {
    (1.0 - o.confidence) / 2.0
}

/// A check before the multiple-testing correction decides its outcome.
pub(crate) fn check(
    (subject, stage, metric): (Subject, Stage, &'static str),
    (baseline, current): (f64, f64),
    (ratio, tails): (Estimate, Option<Tails>),
    reps: (usize, usize),
    (over, gated): (bool, bool),
) -> Check {
    let time = metric == "time_per_step";
    let worse_by = if time { ratio.value - 1.0 } else { 1.0 - ratio.value };
    let (p_worse, p_better) = match tails {
        Some(t) if time => (Some(t.at_most), Some(t.at_least)),
        Some(t) => (Some(t.at_least), Some(t.at_most)),
        None => (None, None),
    };
    Check {
        cell: subject,
        stage,
        metric,
        unit: if time { "s" } else { "1" },
        baseline,
        current,
        baseline_reps: reps.0,
        current_reps: reps.1,
        ratio,
        worse_by,
        p_worse,
        p_better,
        p_worse_holm: None,
        p_better_holm: None,
        design: Design::Separate,
        outcome: Outcome::Unchanged,
        gated,
        oversubscribed: over,
    }
}

/// The paired efficiency check of one cell and stage: Welch's t on the processes' mean
/// logs (`None` when a side has no process with the stage).
fn paired_check(bcell: &Cell, ccell: &Cell, key: &CellKey, stage: Stage, flags: (bool, bool)) -> Option<Check> {
    let (b, c) = (bcell.paired_logs(stage), ccell.paired_logs(stage));
    if b.is_empty() || c.is_empty() {
        return None;
    }
    let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len() as f64;
    let (mb, mc) = (mean(&b), mean(&c));
    let reps = (b.len(), c.len());
    let (ratio, tails) = match super::paired::compare(&b, &c, StatsOptions::default().confidence) {
        Some(w) => (w.ratio, Some(Tails { at_most: w.p_higher, at_least: w.p_lower })),
        None => (Estimate::point((mc - mb).exp(), reps.0.min(reps.1)), None),
    };
    let mut ch =
        check((Subject::Cell(key.clone()), stage, "efficiency"), (mb.exp(), mc.exp()), (ratio, tails), reps, flags);
    ch.design = Design::Paired;
    Some(ch)
}

/// The pooled paired-efficiency check of `stage` over the gated paired cells of `checks`
/// (module docs): the mean change of their mean log efficiencies, `None` with fewer than
/// two such cells or a cell with fewer than two processes a side (no test to pool).
fn pooled_check(base: &Analysis, cur: &Analysis, checks: &[Check], stage: Stage) -> Option<Check> {
    let keys: Vec<&CellKey> = checks
        .iter()
        .filter(|c| c.metric == "efficiency" && c.design == Design::Paired && c.gated && c.stage == stage)
        .filter_map(|c| c.cell.key())
        .collect();
    if keys.len() < 2 {
        return None;
    }
    let logs: Vec<(Vec<f64>, Vec<f64>)> =
        keys.iter().map(|k| (base.cells[*k].paired_logs(stage), cur.cells[*k].paired_logs(stage))).collect();
    let pairs: Vec<(&[f64], &[f64])> = logs.iter().map(|(b, c)| (b.as_slice(), c.as_slice())).collect();
    let w = super::paired::compare_pooled(&pairs, StatsOptions::default().confidence)?;
    let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len() as f64;
    // The geometric means over the cells of each side's (geometric-mean) efficiency.
    let k = logs.len() as f64;
    let (mb, mc) = logs.iter().fold((0.0, 0.0), |(b, c), (x, y)| (b + mean(x) / k, c + mean(y) / k));
    let reps = (logs.iter().map(|(b, _)| b.len()).sum(), logs.iter().map(|(_, c)| c.len()).sum());
    let tails = Tails { at_most: w.p_higher, at_least: w.p_lower };
    let subject = Subject::Pooled { pooled: keys.into_iter().cloned().collect() };
    let mut ch =
        check((subject, stage, "efficiency"), (mb.exp(), mc.exp()), (w.ratio, Some(tails)), reps, (false, true));
    ch.design = Design::Paired;
    Some(ch)
}

/// The time and efficiency checks of one cell measured in both campaigns, and the
/// efficiency checks it could not make (designs that differ).
fn cell_checks(
    base: &Analysis,
    cur: &Analysis,
    key: &CellKey,
    stages: &[Stage],
    include_over: bool,
    metrics: Metrics,
) -> (Vec<Check>, Vec<NotCompared>) {
    let o = StatsOptions::default();
    let (bcell, ccell) = (&base.cells[key], &cur.cells[key]);
    let over = bcell.oversubscribed || ccell.oversubscribed;
    let flags = (over, include_over || !over);
    let mut out = Vec::new();
    let mut skipped = Vec::new();
    for &stage in stages {
        let (bt, ct) = (bcell.times(stage), ccell.times(stage));
        if bt.is_empty() || ct.is_empty() {
            continue;
        }
        let label = format!("{key}/{stage}");
        let reps = (bt.len(), ct.len());
        if metrics.time {
            let t = bootstrap_test(&[ct, bt], &|m| m[0] / m[1], &o, &format!("{label}/time"), 1.0);
            out.push(check(
                (Subject::Cell(key.clone()), stage, "time_per_step"),
                (median(bt), median(ct)),
                t,
                reps,
                flags,
            ));
        }
        if key.threads <= 1 || !metrics.efficiency {
            continue;
        }
        match (bcell.design(), ccell.design()) {
            (Design::Paired, Design::Paired) => {
                out.extend(paired_check(bcell, ccell, key, stage, flags));
                continue;
            }
            (Design::Separate, Design::Separate) => {}
            (b, c) => {
                skipped.push(NotCompared {
                    cell: format!("{key} {stage}"),
                    metric: "efficiency",
                    reason: format!(
                        "measured {} in the baseline and {} in the current campaign: the designs' intervals do not \
                         compare (run both campaigns with the same preset)",
                        b.name(),
                        c.name()
                    ),
                });
                continue;
            }
        }
        let one = CellKey { threads: 1, ..key.clone() };
        let (Some(b1), Some(c1)) = (base.cells.get(&one), cur.cells.get(&one)) else { continue };
        let (b1, c1) = (b1.times(stage), c1.times(stage));
        if b1.is_empty() || c1.is_empty() {
            continue;
        }
        let n = key.threads as f64;
        // samples: current T1, current Tn, baseline T1, baseline Tn
        let e = bootstrap_test(&[c1, ct, b1, bt], &|m| (m[0] / m[1]) / (m[2] / m[3]), &o, &format!("{label}/eff"), 1.0);
        let values = (median(b1) / median(bt) / n, median(c1) / median(ct) / n);
        out.push(check((Subject::Cell(key.clone()), stage, "efficiency"), values, e, reps, flags));
    }
    (out, skipped)
}

/// Each worker's bytes over every sub-stage of one row's counters.
pub(crate) fn worker_totals(w: &std::collections::BTreeMap<mpm_core::Substage, Vec<u64>>) -> Vec<u64> {
    let n = w.values().map(Vec::len).max().unwrap_or(0);
    (0..n).map(|i| w.values().map(|v| v.get(i).copied().unwrap_or(0)).sum()).collect()
}

/// The work counters of a cell measured in both campaigns, compared exactly (`Err`: why
/// they cannot be).
fn work_check(key: &CellKey, bcell: &Cell, ccell: &Cell) -> Result<WorkCheck, String> {
    let (Some(b), Some(c)) = (bcell.work.first(), ccell.work.first()) else {
        return Err("no work counters on one side (CSV schema before 7, or a solver without them)".into());
    };
    for (side, cell) in [("baseline", bcell), ("current", ccell)] {
        if cell.work.iter().any(|w| w != &cell.work[0]) {
            return Err(format!(
                "the {side}'s repetitions counted different work (the counters must repeat exactly: a solver bug?)"
            ));
        }
    }
    let (bw, cw) = (worker_totals(b), worker_totals(c));
    let max = |v: &[u64]| v.iter().copied().max().unwrap_or(0);
    let (changes, more, less) = work_changes(b, c);
    let outcome = if more {
        Outcome::Regressed
    } else if less {
        Outcome::Improved
    } else {
        Outcome::Unchanged
    };
    Ok(WorkCheck {
        cell: key.clone(),
        baseline_bound: bcell.work_bound.first().copied(),
        current_bound: ccell.work_bound.first().copied(),
        baseline_max_worker_bytes: max(&bw),
        current_max_worker_bytes: max(&cw),
        changes,
        outcome,
    })
}

/// Why a baseline cell is not (fully) measured in the current campaign, if it is not.
fn missing(key: &CellKey, bcell: &Cell, ccell: Option<&Cell>, include_over: bool) -> Option<MissingCell> {
    let gated = include_over || !bcell.oversubscribed;
    let named =
        |status: &str, reason: String| MissingCell { cell: key.to_string(), status: status.into(), reason, gated };
    let Some(c) = ccell else {
        return Some(named("missing", "no run of this cell in the current campaign".into()));
    };
    let bad = |s: Status| c.not_ok.iter().filter(|(st, _)| *st == s).map(|(_, r)| r.as_str()).collect::<Vec<_>>();
    for status in [Status::Failed, Status::Invalid] {
        let reasons = bad(status);
        if let Some(first) = reasons.first() {
            let ok = c.times(Stage::Total).len();
            return Some(named(
                status.as_str(),
                format!("{} of {} repetition(s) {}: {first}", reasons.len(), reasons.len() + ok, status.as_str()),
            ));
        }
    }
    if !c.measured() {
        let reasons = bad(Status::Skipped);
        let why = reasons.first().map_or("no measurement".to_string(), |r| r.to_string());
        return Some(named(if reasons.is_empty() { "missing" } else { "skipped" }, why));
    }
    None
}

/// Decide every check's outcome: Holm over the gated checks' p-values per direction, the
/// tolerance alone for checks without p-values, unadjusted p-values for ungated checks.
pub(crate) fn decide(checks: &mut [Check], tol: f64, a: f64) {
    let gated: Vec<usize> = (0..checks.len()).filter(|&i| checks[i].gated && checks[i].p_worse.is_some()).collect();
    for worse in [true, false] {
        let p: Vec<f64> =
            gated.iter().map(|&i| if worse { checks[i].p_worse } else { checks[i].p_better }.unwrap_or(1.0)).collect();
        for (&i, adj) in gated.iter().zip(holm(&p)) {
            if worse {
                checks[i].p_worse_holm = Some(adj);
            } else {
                checks[i].p_better_holm = Some(adj);
            }
        }
    }
    for c in checks.iter_mut() {
        let (pw, pb) = if c.gated { (c.p_worse_holm, c.p_better_holm) } else { (c.p_worse, c.p_better) };
        // No p-value (single repetitions): the tolerance alone decides.
        let (worse_sig, better_sig) = (pw.is_none_or(|p| p <= a), pb.is_none_or(|p| p <= a));
        c.outcome = if c.worse_by > tol && worse_sig {
            Outcome::Regressed
        } else if c.worse_by < -tol && better_sig {
            Outcome::Improved
        } else {
            Outcome::Unchanged
        };
    }
}

/// What [`compare_analyses`] found.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Comparison {
    /// Every timing check with its outcome.
    pub checks: Vec<Check>,
    /// The baseline cells not (fully) measured in the current campaign.
    pub missing: Vec<MissingCell>,
    /// The work counters of every cell measured in both (with `work` among the metrics).
    pub work: Vec<WorkCheck>,
    /// Cells and metrics not compared, and why.
    pub not_compared: Vec<NotCompared>,
}

/// Compare two analyses (the core of `regress`, without file I/O): every check with its
/// outcome, the work counters, and the baseline cells not (fully) measured in the current
/// campaign.
pub fn compare_analyses(
    base: &Analysis,
    cur: &Analysis,
    stages: &[Stage],
    tol: f64,
    include_over: bool,
    metrics: Metrics,
) -> Comparison {
    let mut out = Comparison::default();
    for (key, bcell) in base.cells.iter().filter(|(_, c)| c.measured()) {
        let ccell = cur.cells.get(key);
        if let Some(m) = missing(key, bcell, ccell, include_over) {
            out.missing.push(m);
        }
        let Some(ccell) = ccell.filter(|c| c.measured()) else { continue };
        let (checks, skipped) = cell_checks(base, cur, key, stages, include_over, metrics);
        out.checks.extend(checks);
        out.not_compared.extend(skipped);
        if metrics.work {
            match work_check(key, bcell, ccell) {
                Ok(w) => out.work.push(w),
                Err(reason) => out.not_compared.push(NotCompared { cell: key.to_string(), metric: "work", reason }),
            }
        }
    }
    if metrics.efficiency {
        let pooled: Vec<Check> = stages.iter().filter_map(|&st| pooled_check(base, cur, &out.checks, st)).collect();
        out.checks.extend(pooled);
    }
    decide(&mut out.checks, tol, alpha(&StatsOptions::default()));
    out
}

pub(crate) fn side(c: &Campaign) -> Side {
    Side {
        dir: c.dir.display().to_string(),
        campaign: c.id(),
        fingerprint: c.fingerprint(),
        hardware_class: c.hardware_class().map(|h| h.id()),
    }
}

/// Build the verdict for two results folders (no printing). Unreadable input is an error.
pub fn evaluate(args: &RegressOptions) -> Result<RegressReport> {
    settings(args)?;
    let (base, cur) = load(args)?;
    compare_campaigns(args, &base, &cur)
}

/// The stages and metrics of `args`, checked with its tolerance (bad input is an error
/// before any campaign is read).
fn settings(args: &RegressOptions) -> Result<(Vec<Stage>, Metrics)> {
    if !(args.tolerance >= 0.0 && args.tolerance < 1.0) {
        bail!("--tolerance {} is out of range: give a fraction such as 0.05 for 5 %", args.tolerance);
    }
    let stages: Vec<Stage> = args.stages.iter().map(|s| Stage::parse(s)).collect::<Result<_>>()?;
    Ok((stages, Metrics::parse(&args.metrics)?))
}

/// The two campaigns of `args`, with the rows `regress` keeps: injected rows are compared
/// (that is how the gate is measured; the verdict says so).
pub fn load(args: &RegressOptions) -> Result<(Campaign, Campaign)> {
    let filter = RowFilter::analysis(args.include_noisy).with_injected(true);
    let base = load_campaign(&args.baseline, &filter).context("reading --baseline")?;
    let cur = load_campaign(&args.current, &filter).context("reading --current")?;
    Ok((base, cur))
}

/// The verdict on two loaded campaigns with the settings of `args` (its paths unused; no
/// printing): what [`evaluate`] does after reading them, for callers that compare the same
/// campaigns many times (`calibrate`).
pub fn compare_campaigns(args: &RegressOptions, base: &Campaign, cur: &Campaign) -> Result<RegressReport> {
    let (stages, metrics) = settings(args)?;
    let (bs, cs) = (side(base), side(cur));
    let mut report = blank_report(args, metrics, bs.clone(), cs.clone());
    report.same_rows = same_rows(base, cur);
    if let Some(why) = base.incomparable_with(cur) {
        if !args.force {
            report.reason = format!(
                "{why}: baseline {} vs current {}; compare results of one hardware class, or pass --force",
                bs.fingerprint, cs.fingerprint
            );
            return Ok(report);
        }
        report.forced = true;
    }
    let differ = configuration_differences(&base.configurations, &cur.configurations);
    if !differ.is_empty() {
        report.reason = format!(
            "the campaigns ran different configurations, so their times do not compare: {} (current instead of \
             baseline); compare campaigns of the same preset and overrides",
            differ.join("; ")
        );
        return Ok(report);
    }
    let ba = base.analyse(args.pin.as_deref());
    let ca = cur.analyse(args.pin.as_deref());
    let cmp = compare_analyses(&ba, &ca, &stages, args.tolerance, args.include_oversubscribed, metrics);
    let snapshot = args.work_snapshot.as_deref().map(|p| super::work_snapshot::check_rows(p, &cur.rows)).transpose()?;
    settle(&mut report, cmp, snapshot, &ba, &ca);
    Ok(report)
}

/// Fill `report` from a comparison of the analyses `ba` (baseline) and `ca` (current) and
/// the work snapshot's check, and decide its verdict: what `regress` does after comparing,
/// and `ab` after its pair-by-pair checks.
pub(crate) fn settle(
    report: &mut RegressReport,
    cmp: Comparison,
    snapshot: Option<SnapshotCheck>,
    ba: &Analysis,
    ca: &Analysis,
) {
    let injected = |a: &Analysis| a.cells.values().filter_map(|c| c.injected).reduce(f64::max);
    report.baseline_injected = injected(ba);
    report.current_injected = injected(ca);
    let checks = cmp.checks;
    report.missing_in_current = cmp.missing;
    report.single_repetition = !checks.is_empty() && checks.iter().all(|c| c.p_worse.is_none());
    report.gated_checks = checks.iter().filter(|c| c.gated).count();
    report.regressions = checks.iter().filter(|c| c.gated && c.outcome == Outcome::Regressed).cloned().collect();
    report.improvements = checks.iter().filter(|c| c.gated && c.outcome == Outcome::Improved).cloned().collect();
    report.checks = checks;
    report.work_regressions = cmp.work.iter().filter(|w| w.outcome == Outcome::Regressed).cloned().collect();
    report.work_checks = cmp.work;
    report.not_compared = cmp.not_compared;
    report.work_snapshot = snapshot;
    conclude(report, ba, ca);
}

/// A verdict of `baseline` against `current` with nothing compared yet: `incomparable`, no
/// reason, no check.
pub(crate) fn blank_report(args: &RegressOptions, metrics: Metrics, baseline: Side, current: Side) -> RegressReport {
    RegressReport {
        verdict: "incomparable".into(),
        reason: String::new(),
        tolerance: args.tolerance,
        alpha: alpha(&StatsOptions::default()),
        baseline,
        current,
        forced: false,
        no_baseline: false,
        work_snapshot: None,
        single_repetition: false,
        gated_checks: 0,
        regressions: vec![],
        improvements: vec![],
        checks: vec![],
        missing_in_current: vec![],
        allow_missing: args.allow_missing,
        metrics: [("efficiency", metrics.efficiency), ("time", metrics.time), ("work", metrics.work)]
            .into_iter()
            .filter_map(|(n, on)| on.then_some(n))
            .collect(),
        work_checks: vec![],
        work_regressions: vec![],
        not_compared: vec![],
        baseline_injected: None,
        current_injected: None,
        same_rows: false,
    }
}

/// Whether `a` and `b` hold the same measured rows (campaign, run id and time of every
/// `ok` row), at least one.
fn same_rows(a: &Campaign, b: &Campaign) -> bool {
    let ids = |c: &Campaign| -> std::collections::BTreeSet<(String, String, String)> {
        c.rows
            .iter()
            .filter(|r| r.outcome.status == crate::campaign::store::record::Status::Ok)
            .map(|r| (r.id.campaign_id.clone(), r.id.run_id.clone(), r.id.timestamp.clone()))
            .collect()
    };
    let ia = ids(a);
    !ia.is_empty() && ia == ids(b)
}

/// The verdict and its reason from the checks and the missing cells.
fn conclude(r: &mut RegressReport, base: &Analysis, cur: &Analysis) {
    let tol = 100.0 * r.tolerance;
    let in_common = base.cells.iter().any(|(k, c)| c.measured() && cur.cells.contains_key(k));
    let failing = r.failing_missing().len();
    if !base.cells.values().any(Cell::measured) {
        r.reason = "the baseline has no measured cell: nothing to compare against".into();
        return;
    }
    if !in_common || (r.gated_checks == 0 && r.work_checks.is_empty() && failing == 0) {
        r.reason =
            "no cell of the baseline was run in the current campaign (that is not oversubscribed): nothing to compare"
                .into();
        return;
    }
    let holm = if r.single_repetition {
        "single repetitions: no intervals, the tolerance alone decided".to_string()
    } else {
        format!("Holm-corrected over {} checks at {:.1} % per direction", r.gated_checks, 100.0 * r.alpha)
    };
    let work = if r.work_checks.is_empty() {
        String::new()
    } else {
        format!("; work counters: {} of {} cell(s) moved more bytes", r.work_regressions.len(), r.work_checks.len())
    };
    let snapshot_off = r.work_snapshot.as_ref().is_some_and(|c| !c.changed.is_empty());
    if !r.regressions.is_empty() || failing > 0 || !r.work_regressions.is_empty() || snapshot_off {
        r.verdict = "fail".into();
        r.reason = format!(
            "{} of {} checks got worse by more than {tol:.1} % beyond the noise ({holm}){work}; {failing} baseline cell(s) missing, failed or invalid in the current campaign",
            r.regressions.len(),
            r.gated_checks,
        );
    } else {
        r.verdict = "pass".into();
        r.reason = format!(
            "no check got worse by more than {tol:.1} % beyond the noise ({} checks, {} improved; {holm}){work}",
            r.gated_checks,
            r.improvements.len()
        );
        if !r.missing_in_current.is_empty() {
            r.reason.push_str(&format!("; {} baseline cell(s) not measured, allowed", r.missing_in_current.len()));
        }
    }
    if let Some(c) = &r.work_snapshot {
        r.reason.push_str(&format!("; {}", c.summary()));
    }
    for (side, f) in [("baseline", r.baseline_injected), ("current", r.current_injected)] {
        if let Some(f) = f {
            r.reason.push_str(&format!(
                "; the {side} ran with an injected slowdown of {:.0} % (a test knob: this verdict tests the gate, not \
                 the code)",
                100.0 * f
            ));
        }
    }
}

/// Write the JSON verdict to `path`, or to standard output when `path` is `-`.
pub fn write_json<T: Serialize>(path: &Path, r: &T) -> Result<()> {
    let text = serde_json::to_string_pretty(r)?;
    if path == Path::new("-") {
        println!("{text}");
        return Ok(());
    }
    crate::campaign::store::refuse_record_as_output(path, "--json")?;
    if let Some(parent) = path.parent().filter(|p| !p.as_os_str().is_empty()) {
        std::fs::create_dir_all(parent).with_context(|| format!("cannot create {}", parent.display()))?;
    }
    std::fs::write(path, text)
        .with_context(|| format!("cannot write {}: choose a writable --json path", path.display()))
}

/// The verdict as Markdown: a heading with the verdict, the reason, a table of the checks
/// that changed and of the work counters, what was not compared or is missing.
pub fn markdown(r: &RegressReport) -> String {
    use std::fmt::Write as _;
    let mut s = String::new();
    let icon = match r.verdict.as_str() {
        "pass" => "PASS",
        "fail" => "FAIL",
        _ => "INCOMPARABLE",
    };
    let _ = writeln!(s, "### Parallel-efficiency gate: {icon}\n");
    let _ = writeln!(s, "{}\n", r.reason);
    if r.same_rows {
        let _ = writeln!(s, "**{SAME_ROWS}**\n");
    }
    let _ = writeln!(
        s,
        "Baseline `{}` vs current `{}` (machine `{}`); metrics {}; tolerance {:.1} %, family-wise level {:.1} % per \
         direction.\n",
        r.baseline.campaign,
        r.current.campaign,
        r.current.fingerprint,
        r.metrics.join(", "),
        100.0 * r.tolerance,
        100.0 * r.alpha
    );
    if !r.checks.is_empty() {
        let _ = writeln!(
            s,
            "| cell | stage | metric | design | baseline | current | ratio [95 %] | p worse (Holm) | verdict |"
        );
        let _ = writeln!(s, "|---|---|---|---|---|---|---|---|---|");
        for c in &r.checks {
            let ratio = if c.ratio.lo == c.ratio.hi {
                format!("{:.3}", c.ratio.value)
            } else {
                format!("{:.3} [{:.3}, {:.3}]", c.ratio.value, c.ratio.lo, c.ratio.hi)
            };
            let p = c.p_worse_holm.or(c.p_worse).map_or("-".into(), |p| format!("{p:.3}"));
            let verdict = match (c.outcome, c.gated) {
                (Outcome::Regressed, true) => "**regressed**",
                (Outcome::Improved, true) => "improved",
                (_, false) => "not gated",
                _ => "unchanged",
            };
            let _ = writeln!(
                s,
                "| {} | {} | {} | {} | {} (n={}) | {} (n={}) | {ratio} | {p} | {verdict} |",
                c.cell,
                c.stage.name(),
                c.metric,
                if c.metric == "efficiency" { c.design.name() } else { "-" },
                with_unit(c.baseline, c.unit),
                c.baseline_reps,
                with_unit(c.current, c.unit),
                c.current_reps
            );
        }
        s.push('\n');
    }
    if !r.work_checks.is_empty() {
        let _ = writeln!(s, "| cell | work bound, baseline | current | work counters |");
        let _ = writeln!(s, "|---|---|---|---|");
        for w in &r.work_checks {
            let bound = |b: Option<f64>| b.map_or("-".into(), |b| format!("{b:.3}"));
            let what = match w.outcome {
                Outcome::Unchanged => "equal".to_string(),
                Outcome::Regressed => format!("**more work**: {}", w.changes.join("; ")),
                Outcome::Improved => format!("less work: {}", w.changes.join("; ")),
            };
            let _ = writeln!(s, "| {} | {} | {} | {what} |", w.cell, bound(w.baseline_bound), bound(w.current_bound));
        }
        s.push('\n');
    }
    if let Some(c) = &r.work_snapshot {
        let _ = writeln!(s, "- work snapshot: {}", c.summary());
        for ch in &c.changed {
            let _ = writeln!(s, "  - **{}**: {}", ch.cell, ch.changes.join("; "));
        }
    }
    for m in &r.missing_in_current {
        let _ = writeln!(s, "- {} {}: {}", m.status.to_uppercase(), m.cell, m.reason);
    }
    for (what, cells) in grouped(&r.not_compared) {
        let _ = writeln!(s, "- not compared: {what}: {cells}");
    }
    s
}

/// The cells not compared, one line per metric and reason: (`work: why`, the cells).
fn grouped(n: &[NotCompared]) -> Vec<(String, String)> {
    let mut g: std::collections::BTreeMap<String, Vec<&str>> = std::collections::BTreeMap::new();
    for x in n {
        g.entry(format!("{} ({})", x.metric, x.reason)).or_default().push(&x.cell);
    }
    g.into_iter()
        .map(|(what, cells)| {
            let list = if cells.len() > 3 {
                format!("{} cells ({}, ...)", cells.len(), cells[..3].join(", "))
            } else {
                cells.join(", ")
            };
            (what, list)
        })
        .collect()
}

/// Append `text` to the file at `path` (created when absent).
pub fn append(path: &Path, text: &str) -> Result<()> {
    use std::io::Write as _;
    crate::campaign::store::refuse_record_as_output(path, "--markdown")?;
    if let Some(parent) = path.parent().filter(|p| !p.as_os_str().is_empty()) {
        std::fs::create_dir_all(parent).with_context(|| format!("cannot create {}", parent.display()))?;
    }
    let mut f = std::fs::OpenOptions::new()
        .create(true)
        .append(true)
        .open(path)
        .with_context(|| format!("cannot open {}: choose a writable --markdown path", path.display()))?;
    f.write_all(text.as_bytes()).with_context(|| format!("cannot write {}", path.display()))
}

/// A value with its unit: time per step in s / ms / µs, efficiency as a plain number.
fn with_unit(v: f64, unit: &str) -> String {
    match unit {
        "s" if v.abs() >= 1.0 => format!("{v:.3} s"),
        "s" if v.abs() >= 1e-3 => format!("{:.3} ms", v * 1e3),
        "s" => format!("{:.2} µs", v * 1e6),
        _ => format!("{v:.3}"),
    }
}

/// One console line of a check, with units.
fn check_line(c: &Check) -> String {
    let tag = match c.outcome {
        Outcome::Regressed => "REGRESSED",
        Outcome::Improved => "improved",
        Outcome::Unchanged => "unchanged",
    };
    let what = match (c.unit == "s", c.design) {
        (true, _) => "time/step",
        (false, Design::Paired) => "efficiency (paired)",
        (false, Design::Interleaved) => "efficiency (ab)",
        (false, Design::Separate) => "efficiency",
    };
    let p = c.p_worse_holm.or(c.p_worse).zip(c.p_better_holm.or(c.p_better));
    let change = 100.0 * c.worse_by.abs();
    let words = match (c.unit == "s", c.worse_by > 0.0) {
        (true, true) => format!("{change:.1} % slower"),
        (true, false) => format!("{change:.1} % faster"),
        (false, true) => format!("{change:.1} % less efficient"),
        (false, false) => format!("{change:.1} % more efficient"),
    };
    let ratio = if c.ratio.lo == c.ratio.hi {
        format!("{:.3}", c.ratio.value)
    } else {
        format!("{:.3} [{:.3}, {:.3}]", c.ratio.value, c.ratio.lo, c.ratio.hi)
    };
    format!(
        "  {tag:<10} {:<20} {:<8} {what:<19} baseline {} (n={}) current {} (n={}) ratio {ratio} x ({words}){}{}",
        c.cell.to_string(),
        c.stage.name(),
        with_unit(c.baseline, c.unit),
        c.baseline_reps,
        with_unit(c.current, c.unit),
        c.current_reps,
        p.map_or(String::new(), |(w, b)| format!(", p worse {w:.3} better {b:.3}")),
        if c.gated { "" } else { " (oversubscribed: not gated)" }
    )
}

/// `mpm-bench regress`: prints the verdict, writes the JSON if asked, and returns the exit
/// code (0 pass, 1 regression or missing cell, 2 incomparable). Unreadable input is an
/// error (the CLI exits 2).
pub fn run(args: RegressOptions) -> Result<i32> {
    settings(&args)?;
    if args.missing_baseline_passes && !has_campaign(&args.baseline) {
        return first_baseline(&args);
    }
    let (base, cur) = load(&args)?;
    for c in [&base, &cur] {
        c.note_left_out("regress");
        c.note_hybrid_left_out("regress");
    }
    let r = compare_campaigns(&args, &base, &cur)?;
    emit(&args, &r)
}

/// Whether `dir` holds a campaign (a `runs.csv` at most three levels down).
fn has_campaign(dir: &Path) -> bool {
    super::results::find_campaigns(dir).is_ok_and(|c| !c.is_empty())
}

/// `--missing-baseline pass` without a baseline: the current campaign is read (it must be
/// readable: it is what becomes the baseline), its work counters checked against the
/// snapshot when asked, and the verdict is `pass` unless they are off.
fn first_baseline(args: &RegressOptions) -> Result<i32> {
    let filter = RowFilter::analysis(args.include_noisy).with_injected(true);
    let cur = load_campaign(&args.current, &filter).context("reading --current")?;
    let (_, metrics) = settings(args)?;
    let baseline = Side {
        dir: args.baseline.display().to_string(),
        campaign: String::new(),
        fingerprint: String::new(),
        hardware_class: None,
    };
    let mut r = blank_report(args, metrics, baseline, side(&cur));
    r.verdict = "pass".into();
    r.reason = format!("no baseline yet ({} holds no campaign); this run becomes it", args.baseline.display());
    r.no_baseline = true;
    r.current_injected = cur.analyse(args.pin.as_deref()).cells.values().filter_map(|c| c.injected).reduce(f64::max);
    if let Some(path) = &args.work_snapshot {
        let c = super::work_snapshot::check_rows(path, &cur.rows)?;
        if !c.changed.is_empty() {
            r.verdict = "fail".into();
        }
        r.reason.push_str(&format!("; {}", c.summary()));
        r.work_snapshot = Some(c);
    }
    emit(args, &r)
}

/// Print the verdict, write its JSON and Markdown when asked; the exit code.
fn emit(args: &RegressOptions, r: &RegressReport) -> Result<i32> {
    if let Some(p) = &args.markdown {
        append(p, &markdown(r))?;
    }
    if let Some(p) = &args.json {
        write_json(p, r)?;
        if p == Path::new("-") {
            // The JSON is the standard output: the lines for people go to standard error.
            eprint!("{}", lines(r));
            return Ok(r.exit_code());
        }
    }
    print!("{}", lines(r));
    Ok(r.exit_code())
}

/// The verdict for people, line by line.
pub fn lines(r: &RegressReport) -> String {
    use std::fmt::Write as _;
    let mut s = String::new();
    let _ = writeln!(
        s,
        "regress: baseline {} ({}) vs current {} ({}), tolerance {:.1} %, family-wise level {:.1} % per direction",
        r.baseline.campaign,
        r.baseline.fingerprint,
        r.current.campaign,
        r.current.fingerprint,
        100.0 * r.tolerance,
        100.0 * r.alpha
    );
    if r.same_rows {
        let _ = writeln!(s, "{SAME_ROWS}");
    }
    if r.forced {
        let _ = writeln!(s, "warning: different hardware classes compared (--force)");
    } else if r.baseline.fingerprint != r.current.fingerprint && !r.no_baseline {
        let _ = writeln!(
            s,
            "note: two hosts of one hardware class ({}): compared",
            r.current.hardware_class.as_deref().unwrap_or("unknown")
        );
    }
    for c in r.checks.iter().filter(|c| c.outcome != Outcome::Unchanged) {
        let _ = writeln!(s, "{}", check_line(c));
    }
    let unchanged = r.checks.iter().filter(|c| c.outcome == Outcome::Unchanged).count();
    let _ = writeln!(s, "  {unchanged} check(s) unchanged within {:.1} % or the noise", 100.0 * r.tolerance);
    for w in r.work_checks.iter().filter(|w| w.outcome != Outcome::Unchanged) {
        let tag = if w.outcome == Outcome::Regressed { "MORE WORK" } else { "less work" };
        let _ = writeln!(s, "  {tag:<10} {:<20} work counters: {}", w.cell.to_string(), w.changes.join("; "));
    }
    if !r.work_checks.is_empty() {
        let equal = r.work_checks.iter().filter(|w| w.outcome == Outcome::Unchanged).count();
        let _ = writeln!(s, "  {equal} cell(s) with exactly the baseline's work counters");
    }
    for (what, cells) in grouped(&r.not_compared) {
        let _ = writeln!(s, "  not compared: {what}: {cells}");
    }
    if let Some(c) = &r.work_snapshot {
        for ch in &c.changed {
            let _ = writeln!(s, "  {:<10} {:<28} {}", "SNAPSHOT", ch.cell, ch.changes.join("; "));
        }
    }
    for m in &r.missing_in_current {
        let effect = if !m.gated {
            "oversubscribed: not gated"
        } else if r.allow_missing {
            "allowed by --allow-missing"
        } else {
            "FAILS the gate"
        };
        let _ = writeln!(s, "  {:<10} {:<20} {} ({effect})", m.status.to_uppercase(), m.cell, m.reason);
    }
    let _ = writeln!(s, "verdict: {} — {}", r.verdict, r.reason);
    s
}
