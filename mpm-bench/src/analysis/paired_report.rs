//! `mpm-bench paired`'s report: the measurement of [`crate::campaign::measure::paired`]
//! turned into efficiencies with intervals over the blocks of the one process (the
//! statistics of the paired design are [`super::paired`]'s).

use super::stats::{bootstrap, Estimate, StatsOptions};
use crate::campaign::measure::paired::PairedMeasurement;
use crate::util::median;
use mpm_core::Strategy;
use serde::Serialize;

// ---------------------------------------------------------------------------------------
// `mpm-bench paired`: one process's blocks
// ---------------------------------------------------------------------------------------

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
    /// Median of the paired efficiencies with its bootstrap interval over the blocks of this
    /// one process (it does not cover the spread between processes).
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

/// The whole `mpm-bench paired` result (the JSON file): the measurement and its estimates.
#[derive(Clone, Debug, Serialize)]
pub struct PairedReport {
    /// What was measured (the strategies' blocks are repeated, with their estimates, in
    /// `strategies`).
    #[serde(flatten)]
    pub measured: PairedMeasurement,
    /// One entry per strategy, with its estimates (replaces the measurement's list).
    #[serde(rename = "strategies")]
    pub estimates: Vec<PairedStrategy>,
    /// What the intervals cover.
    pub interval_note: &'static str,
}

/// What `mpm-bench paired`'s intervals cover.
pub const WITHIN_PROCESS_NOTE: &str = "intervals over the blocks of this one process: they do not cover the \
    spread between processes; measure paired cells in a campaign for that";

/// The estimates of a measurement: per strategy the median block efficiency with a
/// bootstrap interval over the blocks, and the paired comparisons.
pub fn report(mut m: PairedMeasurement) -> PairedReport {
    let opts = StatsOptions::default();
    let t = m.threads as f64;
    let min = |v: &[f64]| v.iter().copied().fold(f64::INFINITY, f64::min);
    let first_tt = m.strategies.first().map(|s| s.tt_s_per_step.clone()).unwrap_or_default();
    let estimates = m
        .strategies
        .iter()
        .enumerate()
        .map(|(i, b)| {
            let s = b.strategy;
            let ratios: Vec<f64> = b.t1_s_per_step.iter().zip(&b.tt_s_per_step).map(|(x, y)| x / (t * y)).collect();
            let vs_serial: Vec<f64> = b.t1_s_per_step.iter().zip(&m.serial_s_per_step).map(|(x, y)| x / y).collect();
            let tt_vs_first = (i > 0).then(|| {
                let r: Vec<f64> = b.tt_s_per_step.iter().zip(&first_tt).map(|(x, y)| x / y).collect();
                bootstrap(&[&r], &|v| v[0], &opts, &format!("vs-first-{s}"))
            });
            PairedStrategy {
                strategy: s,
                efficiency: bootstrap(&[&ratios], &|v| v[0], &opts, &format!("paired-{s}")),
                efficiency_of_medians: median(&b.t1_s_per_step) / (t * median(&b.tt_s_per_step)),
                efficiency_of_best: min(&b.t1_s_per_step) / (t * min(&b.tt_s_per_step)),
                one_thread_vs_serial: bootstrap(&[&vs_serial], &|v| v[0], &opts, &format!("vs-serial-{s}")),
                block_efficiency: ratios,
                block_imbalance: b.block_imbalance.clone(),
                tt_vs_first,
                t1_s_per_step: b.t1_s_per_step.clone(),
                tt_s_per_step: b.tt_s_per_step.clone(),
                max_position_difference: b.max_position_difference,
            }
        })
        .collect();
    m.strategies.clear();
    PairedReport { measured: m, estimates, interval_note: WITHIN_PROCESS_NOTE }
}

/// The human-readable result.
pub fn table(r: &PairedReport) -> String {
    let m = &r.measured;
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
        m.model,
        m.particles,
        m.threads,
        cpus(&m.observed_cpus),
        cpus(&m.observed_cpu_one),
        m.blocks,
        m.block_steps,
        m.warmup_steps
    );
    s.push_str(&format!("serial: {:.3} ms per step (median)\n", 1e3 * median(&m.serial_s_per_step)));
    s.push_str(&format!(
        "{:<11} {:>11} {:>11}  {:<24} {:>10} {:>8} {:>10} {:>16}\n",
        "strategy",
        "T1 ms/step",
        format!("T{} ms/step", m.threads),
        "efficiency, paired [95%]",
        "of medians",
        "of best",
        "imbalance",
        "T1 / serial"
    ));
    for p in &r.estimates {
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
    if let Some(first) = r.estimates.first() {
        for p in r.estimates.iter().filter_map(|p| p.tt_vs_first.as_ref().map(|e| (p, e))) {
            s.push_str(&format!(
                "{} / {} at {} threads, paired time per step: {} (below 1: {} is faster)\n",
                p.0.strategy.name(),
                first.strategy.name(),
                m.threads,
                p.1.show(4),
                p.0.strategy.name()
            ));
        }
    }
    s.push_str(&format!("note: {WITHIN_PROCESS_NOTE}\n"));
    for p in &r.estimates {
        if p.max_position_difference.is_nan() || p.max_position_difference >= 1e-9 {
            s.push_str(&format!(
                "WARNING: {} at {} threads ended {:.2e} bar lengths away from its 1-thread run: the runs disagree\n",
                p.strategy, m.threads, p.max_position_difference
            ));
        }
    }
    if m.oversubscribed {
        s.push_str(
            "note: oversubscribed (more workers than usable CPUs): these efficiencies are not scaling figures\n",
        );
    }
    if m.debug_build {
        s.push_str("warning: this harness was built with debug assertions; build with --profile o3 for real numbers\n");
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A real (tiny) measurement: every configuration timed in every block, the parallel
    /// runs agree with the 1-thread runs, and the efficiencies are the ratios of the times.
    #[test]
    fn paired_blocks_time_every_configuration_and_agree() {
        let r = report(
            crate::campaign::measure::paired::measure(&crate::campaign::measure::paired::tests::args()).unwrap(),
        );
        assert_eq!(r.measured.serial_s_per_step.len(), 3);
        assert_eq!(r.estimates.len(), 2);
        for p in &r.estimates {
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
        assert!(t.contains("do not cover the spread between processes"), "{t}");
        assert!(r.estimates[0].tt_vs_first.is_none());
        let v = r.estimates[1].tt_vs_first.as_ref().unwrap();
        let want: Vec<f64> =
            (0..3).map(|b| r.estimates[1].tt_s_per_step[b] / r.estimates[0].tt_s_per_step[b]).collect();
        assert!(v.lo <= v.value && v.value <= v.hi && want.iter().any(|w| (w - v.value).abs() < 1e-12), "{v:?}");
        assert!(!t.contains("WARNING"), "{t}");
        let json = serde_json::to_value(&r).unwrap();
        assert!(json["strategies"][0]["efficiency"]["value"].is_number() && json["model"] == 1, "{json}");
    }
}
