//! `mpm-bench regress`: a CI gate on parallel efficiency and time per step.
//!
//! Compares a current campaign to a baseline campaign cell by cell, like with like: the same
//! machine fingerprint (unless `--force`) and the same (model, strategy, optimisation level,
//! threads) cells, for the stages asked (default: the total step). For each cell measured in
//! both:
//!
//! * time per step: the ratio `T_current / T_baseline` of medians;
//! * parallel efficiency (cells with more than one thread): the ratio
//!   `e_current / e_baseline`, each efficiency `T_1 / (n T_n)` from medians.
//!
//! Each ratio has a percentile-bootstrap interval (every sample involved resampled
//! independently, [`super::stats::bootstrap_test`]) and one-sided bootstrap p-values of
//! "worse" and "better". The p-values of the gated checks are Holm-adjusted
//! ([`super::stats::holm`]) so that the chance of one false alarm over all cells stays at
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
//! Exit code: 0 pass, 1 regression (or a missing cell), 2 error or incomparable (unreadable
//! input, different machines without `--force`, no cell in common). The JSON verdict
//! (`--json FILE`) is written whenever both campaigns could be read.

use super::results::{load_campaign, Campaign};
use super::select::{configuration_differences, RowFilter};
use super::stats::{bootstrap_test, holm, Analysis, Cell, CellKey, Estimate, Stage, StatsOptions, Tails};
use crate::campaign::record::Status;
use crate::util::median;
use anyhow::{bail, Context, Result};
use serde::Serialize;
use std::path::{Path, PathBuf};

/// Compare a campaign to a baseline and fail when efficiency or time per step regressed.
///
/// A check fails when it got worse than --tolerance AND the change is beyond the noise
/// (bootstrap p-value, Holm-corrected over all cells). A baseline cell missing, failed or
/// invalid in the current campaign fails too (unless --allow-missing). Exit code 0 = pass,
/// 1 = regression, 2 = error or incomparable (unreadable input, different machines without
/// --force, no cell in common). Use in CI with a committed baseline campaign.
#[derive(clap::Args, Debug, Clone)]
pub struct RegressArgs {
    /// Baseline results: a campaign folder (holding runs.csv) or a folder containing
    /// campaigns (then the newest is used).
    #[arg(long)]
    pub baseline: PathBuf,
    /// Current results, same forms as --baseline.
    #[arg(long)]
    pub current: PathBuf,
    /// Relative change tolerated before a check can fail (0.05 = 5 %).
    #[arg(long, default_value_t = 0.05)]
    pub tolerance: f64,
    /// Compare even when the machine fingerprints differ (the verdict then compares
    /// different hardware: use with care).
    #[arg(long)]
    pub force: bool,
    /// Write the machine-readable verdict here (JSON).
    #[arg(long)]
    pub json: Option<PathBuf>,
    /// Stages to gate, comma-separated: total, grid, particle.
    #[arg(long, value_delimiter = ',', default_value = "total")]
    pub stages: Vec<String>,
    /// Also gate oversubscribed cells (more threads than cores; noisy).
    #[arg(long)]
    pub include_oversubscribed: bool,
    /// Pinning policy to compare when a campaign has several (default: close, else the first).
    #[arg(long)]
    pub pin: Option<String>,
    /// Keep rows measured on a busy host (host_noisy), left out by default.
    #[arg(long)]
    pub include_noisy: bool,
    /// Do not fail when a baseline cell is missing, failed or invalid in the current
    /// campaign (such cells are still listed).
    #[arg(long)]
    pub allow_missing: bool,
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

/// One metric of one cell.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Check {
    /// The cell.
    pub cell: CellKey,
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
    /// Verdict of the check.
    pub outcome: Outcome,
    /// Whether the check counts for the gate (not oversubscribed, or forced in).
    pub gated: bool,
    /// The cell is oversubscribed in either campaign.
    pub oversubscribed: bool,
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
    /// Machine fingerprint.
    pub fingerprint: String,
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
    /// Fingerprints differ and `--force` was given.
    pub forced: bool,
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
}

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
fn alpha(o: &StatsOptions) -> f64 {
    (1.0 - o.confidence) / 2.0
}

/// A check before the multiple-testing correction decides its outcome.
fn check(
    (key, stage, metric): (&CellKey, Stage, &'static str),
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
        cell: key.clone(),
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
        outcome: Outcome::Unchanged,
        gated,
        oversubscribed: over,
    }
}

/// The time and efficiency checks of one cell measured in both campaigns.
fn cell_checks(base: &Analysis, cur: &Analysis, key: &CellKey, stages: &[Stage], include_over: bool) -> Vec<Check> {
    let o = StatsOptions::default();
    let (bcell, ccell) = (&base.cells[key], &cur.cells[key]);
    let over = bcell.oversubscribed || ccell.oversubscribed;
    let flags = (over, include_over || !over);
    let mut out = Vec::new();
    for &stage in stages {
        let (bt, ct) = (bcell.times(stage), ccell.times(stage));
        if bt.is_empty() || ct.is_empty() {
            continue;
        }
        let label = format!("{key}/{stage}");
        let reps = (bt.len(), ct.len());
        let t = bootstrap_test(&[ct, bt], &|m| m[0] / m[1], &o, &format!("{label}/time"), 1.0);
        out.push(check((key, stage, "time_per_step"), (median(bt), median(ct)), t, reps, flags));
        if key.threads <= 1 {
            continue;
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
        out.push(check((key, stage, "efficiency"), values, e, reps, flags));
    }
    out
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
fn decide(checks: &mut [Check], tol: f64, a: f64) {
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

/// Compare two analyses (the core of `regress`, without file I/O): every check with its
/// outcome, and the baseline cells not (fully) measured in the current campaign.
pub fn compare_analyses(
    base: &Analysis,
    cur: &Analysis,
    stages: &[Stage],
    tol: f64,
    include_over: bool,
) -> (Vec<Check>, Vec<MissingCell>) {
    let mut checks = Vec::new();
    let mut absent = Vec::new();
    for (key, bcell) in base.cells.iter().filter(|(_, c)| c.measured()) {
        let ccell = cur.cells.get(key);
        if let Some(m) = missing(key, bcell, ccell, include_over) {
            absent.push(m);
        }
        if ccell.is_some_and(Cell::measured) {
            checks.extend(cell_checks(base, cur, key, stages, include_over));
        }
    }
    decide(&mut checks, tol, alpha(&StatsOptions::default()));
    (checks, absent)
}

fn side(c: &Campaign) -> Side {
    Side { dir: c.dir.display().to_string(), campaign: c.id(), fingerprint: c.fingerprint() }
}

/// Build the verdict for two results folders (no printing). Unreadable input is an error.
pub fn evaluate(args: &RegressArgs) -> Result<RegressReport> {
    if !(args.tolerance >= 0.0 && args.tolerance < 1.0) {
        bail!("--tolerance {} is out of range: give a fraction such as 0.05 for 5 %", args.tolerance);
    }
    let stages: Vec<Stage> = args.stages.iter().map(|s| Stage::parse(s)).collect::<Result<_>>()?;
    let filter = RowFilter::analysis(args.include_noisy);
    let base = load_campaign(&args.baseline, &filter).context("reading --baseline")?;
    let cur = load_campaign(&args.current, &filter).context("reading --current")?;
    for c in [&base, &cur] {
        c.note_left_out("regress");
        c.note_hybrid_left_out("regress");
    }
    let (bs, cs) = (side(&base), side(&cur));
    let mut report = RegressReport {
        verdict: "incomparable".into(),
        reason: String::new(),
        tolerance: args.tolerance,
        alpha: alpha(&StatsOptions::default()),
        baseline: bs.clone(),
        current: cs.clone(),
        forced: false,
        single_repetition: false,
        gated_checks: 0,
        regressions: vec![],
        improvements: vec![],
        checks: vec![],
        missing_in_current: vec![],
        allow_missing: args.allow_missing,
    };
    if bs.fingerprint != cs.fingerprint {
        if !args.force {
            report.reason = format!(
                "different machines: baseline {} vs current {}; compare results of the same machine, or pass --force",
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
    let (checks, absent) = compare_analyses(&ba, &ca, &stages, args.tolerance, args.include_oversubscribed);
    report.missing_in_current = absent;
    report.single_repetition = !checks.is_empty() && checks.iter().all(|c| c.p_worse.is_none());
    report.gated_checks = checks.iter().filter(|c| c.gated).count();
    report.regressions = checks.iter().filter(|c| c.gated && c.outcome == Outcome::Regressed).cloned().collect();
    report.improvements = checks.iter().filter(|c| c.gated && c.outcome == Outcome::Improved).cloned().collect();
    report.checks = checks;
    conclude(&mut report, &ba, &ca);
    Ok(report)
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
    if !in_common || (r.gated_checks == 0 && failing == 0) {
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
    if !r.regressions.is_empty() || failing > 0 {
        r.verdict = "fail".into();
        r.reason = format!(
            "{} of {} checks got worse by more than {tol:.1} % beyond the noise ({holm}); {failing} baseline cell(s) missing, failed or invalid in the current campaign",
            r.regressions.len(),
            r.gated_checks,
        );
    } else {
        r.verdict = "pass".into();
        r.reason = format!(
            "no check got worse by more than {tol:.1} % beyond the noise ({} checks, {} improved; {holm})",
            r.gated_checks,
            r.improvements.len()
        );
        if !r.missing_in_current.is_empty() {
            r.reason.push_str(&format!("; {} baseline cell(s) not measured, allowed", r.missing_in_current.len()));
        }
    }
}

fn write_json(path: &Path, r: &RegressReport) -> Result<()> {
    if let Some(parent) = path.parent().filter(|p| !p.as_os_str().is_empty()) {
        std::fs::create_dir_all(parent).with_context(|| format!("cannot create {}", parent.display()))?;
    }
    std::fs::write(path, serde_json::to_string_pretty(r)?)
        .with_context(|| format!("cannot write {}: choose a writable --json path", path.display()))
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
    let what = if c.unit == "s" { "time/step" } else { "efficiency" };
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
        "  {tag:<10} {:<20} {:<8} {what:<10} baseline {} (n={}) current {} (n={}) ratio {ratio} x ({words}){}{}",
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
pub fn run(args: RegressArgs) -> Result<i32> {
    let r = evaluate(&args)?;
    if let Some(p) = &args.json {
        write_json(p, &r)?;
    }
    println!(
        "regress: baseline {} ({}) vs current {} ({}), tolerance {:.1} %, family-wise level {:.1} % per direction",
        r.baseline.campaign,
        r.baseline.fingerprint,
        r.current.campaign,
        r.current.fingerprint,
        100.0 * r.tolerance,
        100.0 * r.alpha
    );
    if r.forced {
        println!("warning: different machines compared (--force)");
    }
    for c in r.checks.iter().filter(|c| c.outcome != Outcome::Unchanged) {
        println!("{}", check_line(c));
    }
    let unchanged = r.checks.iter().filter(|c| c.outcome == Outcome::Unchanged).count();
    println!("  {unchanged} check(s) unchanged within {:.1} % or the noise", 100.0 * r.tolerance);
    for m in &r.missing_in_current {
        let effect = if !m.gated {
            "oversubscribed: not gated"
        } else if r.allow_missing {
            "allowed by --allow-missing"
        } else {
            "FAILS the gate"
        };
        println!("  {:<10} {:<20} {} ({effect})", m.status.to_uppercase(), m.cell, m.reason);
    }
    println!("verdict: {} — {}", r.verdict, r.reason);
    Ok(r.exit_code())
}
