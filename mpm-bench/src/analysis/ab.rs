//! `mpm-bench ab`'s verdicts: a baseline build (A) and a candidate build (B) measured side by
//! side in one sitting, their processes paired ([`crate::campaign::schedule::ab`] runs them),
//! compared pair by pair.
//!
//! A pair is one planned run (a cell's repetition) run once by each build, back to back in a
//! seeded ABBA order. For each pair and metric the log ratio `d = ln(B / A)`:
//!
//! * `efficiency`: the process's paired efficiency (its blocks' mean log `T_1 / (T T_T)`,
//!   [`super::stats::PairedProcess`]); cells of two or more threads in the paired design;
//! * `time_per_step`: the `T`-thread solver's steady seconds per step (the total step).
//!
//! Per cell and metric the interval is Student's t over the pairs' log ratios
//! ([`super::paired::compare_pairs`]); per metric one more check pools the cells (the mean of
//! their means). Every check is a member of one Holm family per direction, and a check
//! regresses as in `regress`: worse than the tolerance and beyond the noise. Time per step is
//! gated here, unlike a stored baseline's: the two builds ran on the same host moments apart.
//! The work counters of the two builds are compared exactly ([`super::regress`]'s work
//! check), and the candidate's against the committed snapshot when one is given
//! ([`super::work_snapshot`]). A cell the candidate did not measure (failed, invalid) where
//! the baseline did fails the gate, named, unless allowed.
//!
//! The verdict has `regress`'s shape (the same JSON keys, exit codes, Markdown), with the
//! design (`interleaved`) and the pairs.

use super::paired::compare_pairs;
use super::regress::{self, check, decide, Check, Metrics, RegressOptions, RegressReport, Subject};
use super::results::{load_campaign, Campaign};
use super::select::{configuration_differences, RowFilter};
use super::stats::{CellKey, Design, PairedProcess, Stage, StatsOptions, Tails};
use crate::campaign::store::record::{Row, Status};
use anyhow::{Context, Result};
use serde::Serialize;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// How the intervals are made (written into the verdict).
pub const METHOD: &str = "pairs: each planned run once per build, back to back in a seeded ABBA order (a cell's \
    repetitions alternate which build runs first); per pair the log ratio candidate / baseline of the process's paired \
    efficiency and of its T-thread time per step; per cell Student's t over the pairs' log ratios (n - 1 degrees of \
    freedom), per metric the mean of the cells' means (Welch-Satterthwaite); Holm over every check, per direction.";

/// The settings of an `ab` verdict (the regress-like part of `mpm-bench ab`'s options).
#[derive(Clone, Debug)]
pub struct AbSettings {
    /// Relative change tolerated before a check can fail.
    pub tolerance: f64,
    /// What to gate: efficiency, time, work.
    pub metrics: Vec<String>,
    /// Do not fail when the candidate did not measure a cell the baseline did.
    pub allow_missing: bool,
    /// Check the candidate's work counters against this snapshot.
    pub work_snapshot: Option<PathBuf>,
}

/// Refuse settings that cannot make a verdict, before anything runs.
pub fn check_settings(s: &AbSettings) -> Result<()> {
    Metrics::parse(&s.metrics)?;
    if !(s.tolerance.is_finite() && (0.0..1.0).contains(&s.tolerance)) {
        anyhow::bail!("--tolerance {} is not a fraction in [0, 1) such as 0.05 (5 %)", s.tolerance);
    }
    if let Some(p) = s.work_snapshot.as_deref() {
        super::work_snapshot::read(p)?;
    }
    Ok(())
}

/// The verdict of `mpm-bench ab`.
#[derive(Clone, Debug, Serialize)]
pub struct AbReport {
    /// Always `interleaved`.
    pub design: &'static str,
    /// Pairs compared (both sides `ok`).
    pub pairs: usize,
    /// Pairs left out because a side did not end `ok`.
    pub incomplete_pairs: usize,
    /// How the intervals are made.
    pub method: &'static str,
    /// The verdict, in `regress`'s shape.
    #[serde(flatten)]
    pub gate: RegressReport,
}

impl AbReport {
    /// Exit code: 0 pass, 1 fail, 2 incomparable.
    pub fn exit_code(&self) -> i32 {
        self.gate.exit_code()
    }
}

/// The log ratios of one cell: per metric, the pairs' `ln(B / A)`.
#[derive(Clone, Debug, Default)]
struct CellPairs {
    efficiency: Vec<f64>,
    time: Vec<f64>,
    /// The sides' values (geometric means come from their logs): efficiency, time.
    logs: [(Vec<f64>, Vec<f64>); 2],
}

/// A row's metrics in logs: the paired efficiency (when paired) and the time per step.
fn row_logs(r: &Row) -> (Option<f64>, Option<f64>) {
    let eff = PairedProcess::of(r).and_then(|p| p.log_mean(Stage::Total));
    (eff, Stage::Total.time_per_step(r).map(f64::ln))
}

/// The cell and repetition of a row: what pairs it with the other build's.
fn pair_key(r: &Row) -> (CellKey, u32) {
    (CellKey::new(r.model(), r.strategy(), r.opt().as_str(), r.threads()), r.run.rep)
}

/// Every pair of `ok` rows (the same cell and repetition on both sides), per cell; and the
/// count of pairs with a side not `ok`.
fn pairs(base: &[Row], cand: &[Row]) -> (BTreeMap<CellKey, CellPairs>, usize) {
    let ok = |rows: &[Row]| -> BTreeMap<(CellKey, u32), (Option<f64>, Option<f64>)> {
        rows.iter().filter(|r| r.outcome.status == Status::Ok).map(|r| (pair_key(r), row_logs(r))).collect()
    };
    let (a, b) = (ok(base), ok(cand));
    let planned: std::collections::BTreeSet<(CellKey, u32)> = base.iter().chain(cand).map(pair_key).collect();
    let mut cells: BTreeMap<CellKey, CellPairs> = BTreeMap::new();
    let mut incomplete = 0;
    for k in planned {
        let (Some(x), Some(y)) = (a.get(&k), b.get(&k)) else {
            incomplete += 1;
            continue;
        };
        let c = cells.entry(k.0.clone()).or_default();
        if let (Some(ea), Some(eb)) = (x.0, y.0) {
            c.efficiency.push(eb - ea);
            c.logs[0].0.push(ea);
            c.logs[0].1.push(eb);
        }
        if let (Some(ta), Some(tb)) = (x.1, y.1) {
            c.time.push(tb - ta);
            c.logs[1].0.push(ta);
            c.logs[1].1.push(tb);
        }
    }
    (cells, incomplete)
}

/// The check of one metric over `subject`'s log ratios `d` (one cell, or several pooled);
/// `None` with fewer than two pairs in a cell.
fn pair_check(subject: Subject, metric: &'static str, d: &[&[f64]], sides: (f64, f64), reps: usize) -> Option<Check> {
    let w = compare_pairs(d, StatsOptions::default().confidence)?;
    let tails = Tails { at_most: w.p_higher, at_least: w.p_lower };
    let mut c = check((subject, Stage::Total, metric), sides, (w.ratio, Some(tails)), (reps, reps), (false, true));
    c.design = Design::Interleaved;
    Some(c)
}

/// Every check of the pairs: per cell and metric, and per metric pooled over the cells.
fn pair_checks(cells: &BTreeMap<CellKey, CellPairs>, metrics: Metrics) -> Vec<Check> {
    let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len().max(1) as f64;
    let mut out = Vec::new();
    for (on, metric, idx) in [(metrics.efficiency, "efficiency", 0), (metrics.time, "time_per_step", 1)] {
        if !on {
            continue;
        }
        let d = |c: &CellPairs| if idx == 0 { c.efficiency.clone() } else { c.time.clone() };
        let mut pooled: Vec<(CellKey, Vec<f64>, (f64, f64))> = Vec::new();
        for (key, c) in cells.iter().filter(|(k, _)| idx == 1 || k.threads > 1) {
            let diffs = d(c);
            let sides = (mean(&c.logs[idx].0).exp(), mean(&c.logs[idx].1).exp());
            if let Some(ch) = pair_check(Subject::Cell(key.clone()), metric, &[&diffs], sides, diffs.len()) {
                out.push(ch);
                pooled.push((key.clone(), diffs, (mean(&c.logs[idx].0), mean(&c.logs[idx].1))));
            }
        }
        if pooled.len() >= 2 {
            let k = pooled.len() as f64;
            let sides = pooled.iter().fold((0.0, 0.0), |(a, b), p| (a + p.2 .0 / k, b + p.2 .1 / k));
            let refs: Vec<&[f64]> = pooled.iter().map(|p| p.1.as_slice()).collect();
            let reps = pooled.iter().map(|p| p.1.len()).sum();
            let subject = Subject::Pooled { pooled: pooled.iter().map(|p| p.0.clone()).collect() };
            out.extend(pair_check(subject, metric, &refs, (sides.0.exp(), sides.1.exp()), reps));
        }
    }
    out
}

/// The verdict on the two sides' campaign folders `base` (A) and `cand` (B), which
/// [`crate::campaign::schedule::ab`] ran (any two campaigns of one preset whose rows pair by
/// cell and repetition will do). `labels` name the builds in the verdict.
pub fn judge(settings: &AbSettings, base: &Path, cand: &Path, labels: (&str, &str)) -> Result<AbReport> {
    let metrics = Metrics::parse(&settings.metrics)?;
    // Pairs cancel the host's noise: noisy rows stay; injected ones are the gate's tests.
    let filter = RowFilter::analysis(true).with_injected(true);
    let a = load_campaign(base, &filter).context("reading the baseline side")?;
    let b = load_campaign(cand, &filter).context("reading the candidate side")?;
    let args = RegressOptions {
        tolerance: settings.tolerance,
        metrics: settings.metrics.clone(),
        allow_missing: settings.allow_missing,
        work_snapshot: settings.work_snapshot.clone(),
        ..RegressOptions::new(base, cand)
    };
    let mut sides = (regress::side(&a), regress::side(&b));
    sides.0.campaign = format!("{} ({})", labels.0, sides.0.campaign);
    sides.1.campaign = format!("{} ({})", labels.1, sides.1.campaign);
    let mut gate = regress::blank_report(&args, metrics, sides.0, sides.1);
    let (cells, incomplete) = pairs(&a.rows, &b.rows);
    let pairs_n = cells.values().map(|c| c.time.len().max(c.efficiency.len())).sum();
    let report =
        |gate| AbReport { design: "interleaved", pairs: pairs_n, incomplete_pairs: incomplete, method: METHOD, gate };
    if let Some(why) = incomparable(&a, &b) {
        gate.reason = why;
        return Ok(report(gate));
    }
    let mut checks = pair_checks(&cells, metrics);
    decide(&mut checks, settings.tolerance, regress::alpha(&StatsOptions::default()));
    let (ba, ca) = (a.analyse(None), b.analyse(None));
    let work_only = Metrics { efficiency: false, time: false, work: metrics.work };
    let mut cmp = regress::compare_analyses(&ba, &ca, &[Stage::Total], settings.tolerance, false, work_only);
    cmp.checks = checks;
    let snapshot =
        settings.work_snapshot.as_deref().map(|p| super::work_snapshot::check_rows(p, &b.rows)).transpose()?;
    regress::settle(&mut gate, cmp, snapshot, &ba, &ca);
    Ok(report(gate))
}

/// Why the two sides do not compare: another hardware class, or other configurations.
fn incomparable(a: &Campaign, b: &Campaign) -> Option<String> {
    if let Some(why) = a.incomparable_with(b) {
        return Some(format!("{why}: the two sides of one ab run on one host; were the folders mixed up?"));
    }
    let differ = configuration_differences(&a.configurations, &b.configurations);
    (!differ.is_empty()).then(|| {
        format!("the two sides ran different configurations: {} (candidate instead of baseline)", differ.join("; "))
    })
}

/// The verdict as Markdown (for `$GITHUB_STEP_SUMMARY` or a merge-request note): `regress`'s
/// with the pairs and how they were compared.
pub fn markdown(r: &AbReport) -> String {
    let body = regress::markdown(&r.gate).replacen(
        "### Parallel-efficiency gate:",
        "### Efficiency gate (baseline and candidate side by side):",
        1,
    );
    format!(
        "{body}\n{} pairs ({} incomplete) in ABBA order; intervals: Student's t over the pairs' log ratios, Holm over \
         every check.\n",
        r.pairs, r.incomplete_pairs
    )
}

/// The verdict for people.
pub fn lines(r: &AbReport) -> String {
    let text = regress::lines(&r.gate).replacen("regress: baseline", "ab: baseline", 1);
    format!("{} pairs compared ({} incomplete), ABBA order\n{text}", r.pairs, r.incomplete_pairs)
}

/// Print the verdict (to standard error when the JSON goes to standard output), write its
/// JSON and append its Markdown when asked; the exit code (0 pass, 1 fail, 2 incomparable).
pub fn emit(r: &AbReport, json: Option<&Path>, markdown_to: Option<&Path>) -> Result<i32> {
    if let Some(p) = markdown_to {
        regress::append(p, &markdown(r))?;
    }
    if let Some(p) = json {
        regress::write_json(p, r)?;
        if p == Path::new("-") {
            eprint!("{}", lines(r));
            return Ok(r.exit_code());
        }
    }
    print!("{}", lines(r));
    Ok(r.exit_code())
}
