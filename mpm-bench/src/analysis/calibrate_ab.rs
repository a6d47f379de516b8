//! `mpm-bench calibrate --design ab`'s verdicts: the side-by-side gate (`mpm-bench ab`)
//! measures itself on the host that runs it.
//!
//! [`crate::campaign::measure::calibrate_ab`] runs `N` clean sides of one build and `K` sides
//! with each injected change of known size (an efficiency loss, a step slowdown that leaves
//! the efficiency alone) side by side, process by process, in one sitting. Every two clean
//! sides are an A/A comparison (the earlier side as the baseline): a failed verdict is a
//! false alarm. Every clean side as the baseline against every injected side is an injected
//! comparison: a failed verdict is a detection. Each comparison is `ab`'s own verdict
//! ([`super::ab::judge`]) with the gate's tolerance and metrics.
//!
//! The comparisons reuse sides (7 clean sides give 21 A/A pairs), so they are not
//! independent: the rates are unbiased per comparison but scatter about as much as over the
//! sides. The smallest change found with 90 % power comes from the spread of the pooled
//! check's log ratio over the A/A comparisons ([`min_detectable`]): a check fails when its
//! change is beyond the tolerance and significant after Holm, so a change `d` is found with
//! 90 % power when `ln(1 + d)` is past both `ln(1 + tol) + z_0.9 sd` and
//! `(z_{1 - a/k} + z_0.9) sd`.

use super::ab::{judge as ab_judge, AbSettings};
use crate::campaign::measure::calibrate::CalibrateOptions;
use crate::campaign::measure::calibrate_ab::SideKind;
use crate::campaign::schedule::ab::AbRecord;
use crate::machine::fingerprint;
use crate::machine::topology::Machine;
use crate::util::now_rfc3339;
use anyhow::Result;
use serde::Serialize;
use std::time::Instant;

/// One comparison of two sides.
#[derive(Clone, Debug, Serialize)]
pub struct AbComparison {
    /// `aa`, `efficiency` or `time_per_step` (the injected side's kind).
    pub kind: &'static str,
    /// The baseline side's label.
    pub baseline: String,
    /// The candidate side's label.
    pub candidate: String,
    /// `pass`, `fail` or `incomparable`.
    pub verdict: String,
    /// The metrics whose checks regressed.
    pub failed_metrics: Vec<String>,
    /// Per metric, the pooled check's ratio candidate / baseline.
    pub pooled_ratios: Vec<(String, f64)>,
}

/// One injected change: how often the gate found it.
#[derive(Clone, Debug, Serialize)]
pub struct InjectedKind {
    /// `efficiency` or `time_per_step`.
    pub kind: &'static str,
    /// The injected fraction.
    pub injected_slowdown: f64,
    /// Comparisons of a clean baseline with a side carrying it.
    pub injected_comparisons: usize,
    /// Of those, how many the gate failed.
    pub detected: usize,
    /// The change the comparisons measured: `1 -` the median pooled ratio of the metric
    /// (efficiency) or the median pooled ratio `- 1` (time per step).
    pub measured_change: Option<f64>,
}

/// `calibration.json` of the side-by-side design.
#[derive(Clone, Debug, Serialize)]
pub struct AbCalibration {
    /// Always `ab`.
    pub design: &'static str,
    /// A/A comparisons made.
    pub aa_comparisons: usize,
    /// Of those, how many the gate failed.
    pub false_alarms: usize,
    /// `false_alarms / aa_comparisons`.
    pub false_alarm_rate: Option<f64>,
    /// One entry per injected kind.
    pub injected: Vec<InjectedKind>,
    /// Per metric, the smallest change (a fraction) found with 90 % power by the pooled
    /// check, from the A/A comparisons' spread.
    pub min_detectable_change: Vec<(String, f64)>,
    /// One gate run without the baseline's build (s): two sides of the preset (the longest
    /// two sides' share of this sitting) and the verdict.
    pub gate_wall_s: f64,
    /// The baseline's build, when the command was given one to time (s; `null` otherwise).
    pub baseline_build_s: Option<f64>,
    /// Pairs per side (planned runs of the preset).
    pub pairs_per_side: usize,
    /// The gate's settings.
    pub tolerance: f64,
    /// The gate's metrics.
    pub metrics: Vec<String>,
    /// The preset.
    pub preset: String,
    /// What ran, in which order.
    pub record: AbRecord,
    /// Every comparison.
    pub comparisons: Vec<AbComparison>,
    /// How the comparisons were formed.
    pub method: &'static str,
    /// Machine fingerprint.
    pub machine: String,
    /// When it finished (RFC 3339).
    pub timestamp: String,
    /// The command line.
    pub command_line: String,
}

/// How the comparisons are formed (written into calibration.json).
pub const METHOD: &str = "Side by side: N clean sides of one build and K sides per injected change ran process by \
    process in one sitting (each planned run once per side, the sides in a seeded permutation and its reverse, \
    alternating). A/A: every pair of clean sides, the earlier as the baseline; injected: every clean side as the \
    baseline against every side with the change. Each comparison is mpm-bench ab's verdict. Pairs reuse sides, so the \
    comparisons are not independent: the rates are unbiased per comparison but scatter about as much as over the \
    sides. min_detectable_change: from the spread of the pooled check's log ratio over the A/A comparisons, the change \
    that clears the tolerance and the Holm level with 90 % power.";

/// Standard normal quantile (Acklam's rational approximation, |error| < 1.2e-9).
fn normal_quantile(p: f64) -> f64 {
    super::paired::student_t_quantile(p, 1e6)
}

/// The smallest change found with 90 % power by a check whose log ratio scatters by `sd`
/// under no change, at tolerance `tol`, among `checks` checks at family-wise level `alpha`.
pub fn min_detectable(sd: f64, tol: f64, checks: usize, alpha: f64) -> f64 {
    let z_power = normal_quantile(0.9);
    let z_alpha = normal_quantile(1.0 - alpha / checks.max(1) as f64);
    let need = ((1.0 + tol).ln() + z_power * sd).max((z_alpha + z_power) * sd);
    need.exp() - 1.0
}

/// Judge every comparison of the sides in `record` (of the kinds `kinds`) with `a`'s gate
/// settings.
pub fn judge(a: &CalibrateOptions, machine: &Machine, record: AbRecord, kinds: &[SideKind]) -> Result<AbCalibration> {
    let settings =
        AbSettings { tolerance: a.tolerance, metrics: a.metrics.clone(), allow_missing: false, work_snapshot: None };
    let sides = &record.sides;
    let clean: Vec<usize> = (0..sides.len()).filter(|&i| kinds[i] == SideKind::Clean).collect();
    let mut comparisons = Vec::new();
    let mut verdict_s: f64 = 0.0;
    let mut compare = |kind: &'static str, i: usize, j: usize| -> Result<()> {
        let t0 = Instant::now();
        let labels = (sides[i].label.as_str(), sides[j].label.as_str());
        let r = ab_judge(&settings, &sides[i].dir, &sides[j].dir, labels)?;
        verdict_s = verdict_s.max(t0.elapsed().as_secs_f64());
        let failed_metrics = r
            .gate
            .checks
            .iter()
            .filter(|c| c.outcome == super::regress::Outcome::Regressed)
            .map(|c| c.metric.to_string())
            .collect::<std::collections::BTreeSet<_>>()
            .into_iter()
            .collect();
        let pooled_ratios = r
            .gate
            .checks
            .iter()
            .filter(|c| c.cell.key().is_none())
            .map(|c| (c.metric.to_string(), c.ratio.value))
            .collect();
        comparisons.push(AbComparison {
            kind,
            baseline: sides[i].label.clone(),
            candidate: sides[j].label.clone(),
            verdict: r.gate.verdict.clone(),
            failed_metrics,
            pooled_ratios,
        });
        Ok(())
    };
    for (x, &i) in clean.iter().enumerate() {
        for &j in &clean[x + 1..] {
            compare("aa", i, j)?;
        }
    }
    for kind in [SideKind::Efficiency, SideKind::Step] {
        for &i in &clean {
            for j in (0..sides.len()).filter(|&j| kinds[j] == kind) {
                compare(kind.name(), i, j)?;
            }
        }
    }
    Ok(summarise(a, machine, record, comparisons, verdict_s))
}

/// The calibration from its comparisons.
fn summarise(
    a: &CalibrateOptions,
    machine: &Machine,
    record: AbRecord,
    comparisons: Vec<AbComparison>,
    verdict_s: f64,
) -> AbCalibration {
    let aa: Vec<&AbComparison> = comparisons.iter().filter(|c| c.kind == "aa").collect();
    let false_alarms = aa.iter().filter(|c| c.verdict == "fail").count();
    let median = |mut v: Vec<f64>| -> Option<f64> {
        v.sort_by(f64::total_cmp);
        (!v.is_empty()).then(|| v[v.len() / 2])
    };
    let pooled = |c: &AbComparison, m: &str| c.pooled_ratios.iter().find(|(k, _)| k == m).map(|(_, r)| *r);
    let injected = [(SideKind::Efficiency, a.inject_slowdown), (SideKind::Step, a.inject_step_slowdown)]
        .into_iter()
        .map(|(kind, f)| {
            let of: Vec<&AbComparison> = comparisons.iter().filter(|c| c.kind == kind.name()).collect();
            let measured_change = match kind {
                SideKind::Step => {
                    median(of.iter().filter_map(|c| pooled(c, "time_per_step")).collect()).map(|r| r - 1.0)
                }
                _ => median(of.iter().filter_map(|c| pooled(c, "efficiency")).collect()).map(|r| 1.0 - r),
            };
            InjectedKind {
                kind: kind.name(),
                injected_slowdown: f,
                injected_comparisons: of.len(),
                detected: of.iter().filter(|c| c.verdict == "fail").count(),
                measured_change,
            }
        })
        .collect();
    let checks = aa.first().map_or(1, |c| c.pooled_ratios.len().max(1));
    let min_detectable_change = ["efficiency", "time_per_step"]
        .into_iter()
        .filter_map(|m| {
            let logs: Vec<f64> = aa.iter().filter_map(|c| pooled(c, m)).map(f64::ln).collect();
            let n = logs.len() as f64;
            (logs.len() >= 3).then(|| {
                let mean = logs.iter().sum::<f64>() / n;
                let sd = (logs.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (n - 1.0)).sqrt();
                (m.to_string(), min_detectable(sd, a.tolerance, 2 * checks, 0.05))
            })
        })
        .collect();
    let sides = record.sides.len().max(1) as f64;
    let pairs_per_side = record.order.len();
    AbCalibration {
        design: "ab",
        aa_comparisons: aa.len(),
        false_alarms,
        false_alarm_rate: (!aa.is_empty()).then(|| false_alarms as f64 / aa.len() as f64),
        injected,
        min_detectable_change,
        gate_wall_s: 2.0 * record.wall_s / sides + verdict_s,
        baseline_build_s: None,
        pairs_per_side,
        tolerance: a.tolerance,
        metrics: a.metrics.clone(),
        preset: a.preset.clone(),
        record,
        comparisons,
        method: METHOD,
        machine: fingerprint::fingerprint(machine),
        timestamp: now_rfc3339(),
        command_line: std::env::args().collect::<Vec<_>>().join(" "),
    }
}

/// The calibration for people.
pub fn table(c: &AbCalibration) -> String {
    use std::fmt::Write as _;
    let mut s = String::new();
    let rate = |n: usize, of: usize| {
        if of == 0 {
            "n/a".to_string()
        } else {
            format!("{:.0} %", 100.0 * n as f64 / of as f64)
        }
    };
    let _ =
        writeln!(s, "calibration of the side-by-side gate (ab) on {} ({} pairs per side)", c.machine, c.pairs_per_side);
    let _ = writeln!(
        s,
        "  A/A comparisons: {}, false alarms: {} ({})",
        c.aa_comparisons,
        c.false_alarms,
        rate(c.false_alarms, c.aa_comparisons)
    );
    for k in &c.injected {
        let _ = writeln!(
            s,
            "  injected {} change of {:.0} %: found in {} of {} ({}); measured {}",
            k.kind,
            100.0 * k.injected_slowdown,
            k.detected,
            k.injected_comparisons,
            rate(k.detected, k.injected_comparisons),
            k.measured_change.map_or("n/a".into(), |m| format!("{:.1} %", 100.0 * m))
        );
    }
    for (m, d) in &c.min_detectable_change {
        let _ = writeln!(s, "  smallest {m} change found with 90 % power (every cell): {:.1} %", 100.0 * d);
    }
    let _ = writeln!(s, "  one gate run without the baseline's build: {:.0} s", c.gate_wall_s);
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    /// With no noise the tolerance decides; with noise the power term adds; more checks
    /// raise the bar.
    #[test]
    fn the_smallest_change_found_grows_with_the_noise() {
        assert!((min_detectable(0.0, 0.05, 4, 0.05) - 0.05).abs() < 1e-12);
        let quiet = min_detectable(0.01, 0.05, 4, 0.05);
        let noisy = min_detectable(0.05, 0.05, 4, 0.05);
        assert!(quiet > 0.05 && quiet < 0.08, "{quiet}");
        assert!(noisy > 0.17 && noisy < 0.25, "{noisy}: (z_0.99375 + z_0.9) x 0.05 = 0.19 in logs");
        assert!(min_detectable(0.05, 0.05, 40, 0.05) > noisy);
    }
}
