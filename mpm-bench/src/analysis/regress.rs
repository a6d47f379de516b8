//! `mpm-bench regress`: a CI gate on parallel efficiency and time per step.
//!
//! Compares a current campaign to a baseline campaign cell by cell, like with like: the same
//! machine fingerprint (unless `--force`) and the same (model, strategy, optimisation level,
//! threads) cells, for the stages asked (default: the total step). For each cell present in
//! both:
//!
//! * time per step: the ratio `T_current / T_baseline` of medians;
//! * parallel efficiency (cells with more than one thread): the ratio
//!   `e_current / e_baseline`, each efficiency `T_1 / (n T_n)` from medians.
//!
//! Each ratio has a percentile-bootstrap interval (every sample involved resampled
//! independently, [`super::stats::bootstrap`]). A check *regresses* when the change is worse
//! than the tolerance (time ratio above `1 + tol`, efficiency ratio below `1 - tol`) **and**
//! the interval excludes no change (1). It *improves* when better than the tolerance and the
//! interval excludes 1; otherwise it is *unchanged*. With single repetitions the intervals
//! are points, so the tolerance alone decides (the verdict says so).
//!
//! Oversubscribed cells (more threads than cores) are time sharing and very noisy: they are
//! compared and listed, but not gated unless `--include-oversubscribed`.
//!
//! Exit code: 0 pass, 1 regression (the CLI's `run` returns it), and an error (non-zero)
//! when the two sets cannot be compared (different machines without `--force`, no common
//! cell). The JSON verdict (`--json FILE`) is written in every case.

use super::results::{load_campaign, Campaign};
use super::stats::{bootstrap, Analysis, CellKey, Estimate, Stage, StatsOptions};
use crate::util::median;
use anyhow::{bail, Context, Result};
use serde::Serialize;
use std::path::{Path, PathBuf};

/// Compare a campaign to a baseline and fail when efficiency or time per step regressed.
///
/// A check fails when it got worse than --tolerance AND its bootstrap interval excludes no
/// change. Exit code 0 = pass, 1 = regression; errors (different machines without --force,
/// nothing in common) exit non-zero too. Use in CI with a committed baseline campaign.
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
}

/// What one check found.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Outcome {
    /// Worse beyond the tolerance and the interval excludes no change.
    Regressed,
    /// Better beyond the tolerance and the interval excludes no change.
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
    /// Baseline value (s, or efficiency).
    pub baseline: f64,
    /// Current value.
    pub current: f64,
    /// current / baseline, with its interval.
    pub ratio: Estimate,
    /// Relative change in the "worse" direction (positive = worse): `ratio - 1` for time,
    /// `1 - ratio` for efficiency.
    pub worse_by: f64,
    /// Verdict of the check.
    pub outcome: Outcome,
    /// Whether the check counts for the gate (not oversubscribed, or forced in).
    pub gated: bool,
    /// The cell is oversubscribed in either campaign.
    pub oversubscribed: bool,
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
    /// Tolerance used.
    pub tolerance: f64,
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
    /// Baseline cells with no measurement in the current campaign.
    pub missing_in_current: Vec<String>,
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
}

fn outcome(worse_by: f64, ratio: &Estimate, tol: f64, worse_is_up: bool) -> Outcome {
    // Does the interval exclude "no change" (1) on the worse / better side? With a
    // degenerate interval (single repetitions) it cannot say: the tolerance alone decides.
    let (above, below) = (ratio.lo > 1.0 || ratio.degenerate(), ratio.hi < 1.0 || ratio.degenerate());
    let (worse_side, better_side) = if worse_is_up { (above, below) } else { (below, above) };
    if worse_by > tol && worse_side {
        Outcome::Regressed
    } else if worse_by < -tol && better_side {
        Outcome::Improved
    } else {
        Outcome::Unchanged
    }
}

/// Compare two analyses (the core of `regress`, without file I/O).
pub fn compare_analyses(
    base: &Analysis,
    cur: &Analysis,
    stages: &[Stage],
    tol: f64,
    include_over: bool,
) -> (Vec<Check>, Vec<String>) {
    let o = StatsOptions::default();
    let mut checks = Vec::new();
    let mut missing = Vec::new();
    for (key, bcell) in &base.cells {
        if !bcell.measured() {
            continue;
        }
        let Some(ccell) = cur.cells.get(key).filter(|c| c.measured()) else {
            missing.push(key.to_string());
            continue;
        };
        let over = bcell.oversubscribed || ccell.oversubscribed;
        for &stage in stages {
            let (bt, ct) = (bcell.times(stage), ccell.times(stage));
            if bt.is_empty() || ct.is_empty() {
                continue;
            }
            let label = format!("{key}/{stage}");
            let ratio = bootstrap(&[ct, bt], &|m| m[0] / m[1], &o, &format!("{label}/time"));
            let worse_by = ratio.value - 1.0;
            checks.push(Check {
                cell: key.clone(),
                stage,
                metric: "time_per_step",
                baseline: median(bt),
                current: median(ct),
                ratio,
                worse_by,
                outcome: outcome(worse_by, &ratio, tol, true),
                gated: include_over || !over,
                oversubscribed: over,
            });
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
            let ratio = bootstrap(&[c1, ct, b1, bt], &|m| (m[0] / m[1]) / (m[2] / m[3]), &o, &format!("{label}/eff"));
            let worse_by = 1.0 - ratio.value;
            checks.push(Check {
                cell: key.clone(),
                stage,
                metric: "efficiency",
                baseline: median(b1) / median(bt) / n,
                current: median(c1) / median(ct) / n,
                ratio,
                worse_by,
                outcome: outcome(worse_by, &ratio, tol, false),
                gated: include_over || !over,
                oversubscribed: over,
            });
        }
    }
    (checks, missing)
}

fn side(c: &Campaign) -> Side {
    Side { dir: c.dir.display().to_string(), campaign: c.id(), fingerprint: c.fingerprint() }
}

/// Build the verdict for two results folders (no printing).
pub fn evaluate(args: &RegressArgs) -> Result<RegressReport> {
    if !(args.tolerance >= 0.0 && args.tolerance < 1.0) {
        bail!("--tolerance {} is out of range: give a fraction such as 0.05 for 5 %", args.tolerance);
    }
    let stages: Vec<Stage> = args.stages.iter().map(|s| Stage::parse(s)).collect::<Result<_>>()?;
    let base = load_campaign(&args.baseline).context("reading --baseline")?.without_noisy(args.include_noisy);
    let cur = load_campaign(&args.current).context("reading --current")?.without_noisy(args.include_noisy);
    let (bs, cs) = (side(&base), side(&cur));
    let mut report = RegressReport {
        verdict: "incomparable".into(),
        reason: String::new(),
        tolerance: args.tolerance,
        baseline: bs.clone(),
        current: cs.clone(),
        forced: false,
        single_repetition: false,
        gated_checks: 0,
        regressions: vec![],
        improvements: vec![],
        checks: vec![],
        missing_in_current: vec![],
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
    let ba = base.analyse(args.pin.as_deref());
    let ca = cur.analyse(args.pin.as_deref());
    let (checks, missing) = compare_analyses(&ba, &ca, &stages, args.tolerance, args.include_oversubscribed);
    report.missing_in_current = missing;
    report.single_repetition = checks.iter().all(|c| c.ratio.degenerate());
    report.gated_checks = checks.iter().filter(|c| c.gated).count();
    report.regressions = checks.iter().filter(|c| c.gated && c.outcome == Outcome::Regressed).cloned().collect();
    report.improvements = checks.iter().filter(|c| c.gated && c.outcome == Outcome::Improved).cloned().collect();
    report.checks = checks;
    if report.gated_checks == 0 {
        report.reason = "no cell measured in both campaigns (that is not oversubscribed): nothing to compare".into();
    } else if !report.regressions.is_empty() {
        report.verdict = "fail".into();
        report.reason = format!(
            "{} of {} checks got worse by more than {:.1} % with an interval excluding no change",
            report.regressions.len(),
            report.gated_checks,
            100.0 * args.tolerance
        );
    } else {
        report.verdict = "pass".into();
        report.reason = format!(
            "no check got worse by more than {:.1} % beyond the noise ({} checks, {} improved)",
            100.0 * args.tolerance,
            report.gated_checks,
            report.improvements.len()
        );
    }
    if report.single_repetition && report.gated_checks > 0 {
        report.reason.push_str("; single repetitions: no intervals, the tolerance alone decided");
    }
    Ok(report)
}

fn write_json(path: &Path, r: &RegressReport) -> Result<()> {
    if let Some(parent) = path.parent().filter(|p| !p.as_os_str().is_empty()) {
        std::fs::create_dir_all(parent).with_context(|| format!("cannot create {}", parent.display()))?;
    }
    std::fs::write(path, serde_json::to_string_pretty(r)?)
        .with_context(|| format!("cannot write {}: choose a writable --json path", path.display()))
}

/// `mpm-bench regress`: prints the verdict, writes the JSON if asked, and returns the exit
/// code (0 pass, 1 regression). Incomparable sets are an error (after the JSON is written).
pub fn run(args: RegressArgs) -> Result<i32> {
    let r = evaluate(&args)?;
    if let Some(p) = &args.json {
        write_json(p, &r)?;
    }
    println!(
        "regress: baseline {} ({}) vs current {} ({}), tolerance {:.1} %",
        r.baseline.campaign,
        r.baseline.fingerprint,
        r.current.campaign,
        r.current.fingerprint,
        100.0 * r.tolerance
    );
    if r.forced {
        println!("warning: different machines compared (--force)");
    }
    for c in r.checks.iter().filter(|c| c.outcome != Outcome::Unchanged) {
        println!(
            "  {:<10} {:<26} {:<8} {:<13} baseline {:.4} current {:.4} ratio {}{}",
            match c.outcome {
                Outcome::Regressed => "REGRESSED",
                Outcome::Improved => "improved",
                Outcome::Unchanged => "",
            },
            c.cell.to_string(),
            c.stage.name(),
            c.metric,
            c.baseline,
            c.current,
            c.ratio.show(3),
            if c.gated { "" } else { " (oversubscribed: not gated)" }
        );
    }
    if !r.missing_in_current.is_empty() {
        println!("  not measured in the current campaign: {}", r.missing_in_current.join(", "));
    }
    println!("verdict: {} — {}", r.verdict, r.reason);
    if r.verdict == "incomparable" {
        bail!("regress: {}", r.reason);
    }
    Ok(r.exit_code())
}
