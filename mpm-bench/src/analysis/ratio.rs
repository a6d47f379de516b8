//! Campaign B over campaign A on their matching cells: per-cell ratios of time per step and of
//! particle-steps per second, the headline per model (median over the matching cells with a
//! 95 % bootstrap interval), and the cells left out with the reason.
//!
//! A cell is model x strategy x threads x optimisation level x pinning policy. It is compared
//! only when both campaigns measured it under the same pinning policy and neither ran it
//! oversubscribed (time sharing says nothing about the hardware's speed).

use super::stats::{bootstrap, Analysis, Cell, CellKey, Estimate, Stage, StatsOptions};
use serde::Serialize;

/// The ratios of one matching cell.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct CellRatio {
    /// The cell.
    pub key: CellKey,
    /// Median time per step on A (s).
    pub time_a: Estimate,
    /// Median time per step on B (s).
    pub time_b: Estimate,
    /// Time per step, B over A (below 1: B is faster).
    pub time_ratio: Estimate,
    /// Particle-steps per second, B over A (above 1: B is faster).
    pub throughput_ratio: Estimate,
    /// Some repetition on either side was measured on a busy host.
    pub noisy: bool,
}

/// A cell not compared, and why.
#[derive(Clone, Debug, PartialEq, Eq, Serialize)]
pub struct LeftOut {
    /// The cell (`Model1 AE O3 4t`).
    pub cell: String,
    /// Why it is left out.
    pub reason: String,
}

/// The headline of one model: medians over its matching cells.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Headline {
    /// Model number.
    pub model: u32,
    /// Matching cells the medians are over.
    pub cells: usize,
    /// Median over cells of the time-per-step ratio B / A, with its interval.
    pub time_ratio: Estimate,
    /// Median over cells of the throughput ratio B / A, with its interval.
    pub throughput_ratio: Estimate,
}

/// B compared with A.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct Comparison {
    /// Ratios of every matching cell, by cell.
    pub cells: Vec<CellRatio>,
    /// Cells of either campaign that are not compared.
    pub left_out: Vec<LeftOut>,
    /// One headline per model with at least one matching cell.
    pub headlines: Vec<Headline>,
}

/// Median of a slice (NaN when empty).
fn median(v: &[f64]) -> f64 {
    let mut s = v.to_vec();
    s.sort_by(f64::total_cmp);
    match s.len() {
        0 => f64::NAN,
        n if n % 2 == 1 => s[n / 2],
        n => 0.5 * (s[n / 2 - 1] + s[n / 2]),
    }
}

/// Why the cell `key` cannot be compared, or `None` when it can.
fn why_not(key: &CellKey, a: Option<&Cell>, b: Option<&Cell>) -> Option<String> {
    let side = |c: Option<&Cell>, name: &str| -> Option<String> {
        let Some(c) = c else { return Some(format!("not in {name}")) };
        if !c.measured() {
            let why = c.not_ok.first().map_or("no measurement".to_string(), |(s, r)| format!("{}: {r}", s.as_str()));
            return Some(format!("not measured on {name} ({why})"));
        }
        c.oversubscribed.then(|| format!("oversubscribed on {name} ({} threads: time sharing)", key.threads))
    };
    side(a, "A").or_else(|| side(b, "B"))
}

/// Particles of B over particles of A (1 when either is unknown).
fn particle_factor(a: &Cell, b: &Cell) -> f64 {
    match (a.particles, b.particles) {
        (Some(pa), Some(pb)) if pa > 0 => pb as f64 / pa as f64,
        _ => 1.0,
    }
}

/// Compare `b` with `a` on the total step.
pub fn compare(a: &Analysis, b: &Analysis, opts: &StatsOptions) -> Comparison {
    let mut out = Comparison::default();
    let keys: std::collections::BTreeSet<&CellKey> = a.cells.keys().chain(b.cells.keys()).collect();
    let pins_differ = a.pin_policy != b.pin_policy;
    let mut pairs: Vec<(&CellKey, &Cell, &Cell)> = Vec::new();
    for key in keys {
        let (ca, cb) = (a.cells.get(key), b.cells.get(key));
        let reason = if pins_differ {
            Some(format!("pinning differs: {} on A, {} on B", a.pin_policy, b.pin_policy))
        } else {
            why_not(key, ca, cb)
        };
        match (reason, ca, cb) {
            (None, Some(ca), Some(cb)) => pairs.push((key, ca, cb)),
            (r, ..) => out.left_out.push(LeftOut { cell: key.to_string(), reason: r.unwrap_or_default() }),
        }
    }
    for &(key, ca, cb) in &pairs {
        let (ta, tb) = (ca.times(Stage::Total), cb.times(Stage::Total));
        let k = particle_factor(ca, cb);
        out.cells.push(CellRatio {
            key: key.clone(),
            time_a: bootstrap(&[ta], &|m| m[0], opts, &format!("{key}/a")),
            time_b: bootstrap(&[tb], &|m| m[0], opts, &format!("{key}/b")),
            time_ratio: bootstrap(&[tb, ta], &|m| m[0] / m[1], opts, &format!("{key}/ratio")),
            throughput_ratio: bootstrap(&[ta, tb], &|m| k * m[0] / m[1], opts, &format!("{key}/thr")),
            noisy: ca.noisy + cb.noisy > 0,
        });
    }
    let models: std::collections::BTreeSet<u32> = pairs.iter().map(|p| p.0.model).collect();
    for model in models {
        let of: Vec<&(&CellKey, &Cell, &Cell)> = pairs.iter().filter(|p| p.0.model == model).collect();
        out.headlines.push(headline(model, &of, opts));
    }
    out
}

/// The medians over cells of one model, resampling every cell's repetitions on both sides.
fn headline(model: u32, pairs: &[&(&CellKey, &Cell, &Cell)], opts: &StatsOptions) -> Headline {
    // Samples alternate B, A per cell, so the statistic sees medians in that order.
    let samples: Vec<&[f64]> =
        pairs.iter().flat_map(|(_, a, b)| [b.times(Stage::Total), a.times(Stage::Total)]).collect();
    let factors: Vec<f64> = pairs.iter().map(|(_, a, b)| particle_factor(a, b)).collect();
    let time = |m: &[f64]| median(&m.chunks(2).map(|c| c[0] / c[1]).collect::<Vec<_>>());
    let thr = |m: &[f64]| median(&m.chunks(2).zip(&factors).map(|(c, k)| k * c[1] / c[0]).collect::<Vec<_>>());
    Headline {
        model,
        cells: pairs.len(),
        time_ratio: bootstrap(&samples, &time, opts, &format!("headline/{model}/time")),
        throughput_ratio: bootstrap(&samples, &thr, opts, &format!("headline/{model}/thr")),
    }
}

#[cfg(test)]
mod tests {
    use super::median;

    #[test]
    fn median_of_odd_even_and_empty() {
        assert_eq!(median(&[3.0, 1.0, 2.0]), 2.0);
        assert_eq!(median(&[4.0, 1.0, 2.0, 3.0]), 2.5);
        assert!(median(&[]).is_nan());
    }
}
