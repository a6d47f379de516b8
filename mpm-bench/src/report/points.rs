//! The points the figures draw from an analysis: a cell's speedup or efficiency
//! ([`plot_point`]) and a series' peak memory ([`memory_points`]), shared by the paper's
//! figures (`figures.rs`) and the strategies figure (`strategies.rs`).

use super::plot::PlotPoint;
use crate::analysis::stats::{Analysis, CellKey, Point, StatsOptions};
use mpm_core::Strategy;

/// Speedup or efficiency.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Metric {
    /// `T1 / Tn`.
    Speedup,
    /// `speedup / n`.
    Efficiency,
}

/// The point of `p` for `metric` (none where the cell has no such figure).
pub(super) fn plot_point(p: &Point, metric: Metric) -> Option<PlotPoint> {
    let e = match metric {
        Metric::Speedup => p.speedup?,
        Metric::Efficiency => p.efficiency?,
    };
    Some(PlotPoint {
        x: p.key.threads as f64,
        y: e.value,
        lo: e.lo,
        hi: e.hi,
        hollow: p.oversubscribed,
        grey: p.noisy,
        flagged: !p.flags.is_empty(),
    })
}

/// Bytes per GiB.
const GIB: f64 = (1u64 << 30) as f64;

/// Peak memory (GiB) of model `m`, `strat`, `opt` by thread count, and the thread counts
/// whose runs were skipped or failed.
pub(super) fn memory_points(an: &Analysis, m: u32, strat: Strategy, opt: &str) -> (Vec<PlotPoint>, Vec<String>) {
    let o = StatsOptions::default();
    let mut pts = Vec::new();
    let mut skipped = Vec::new();
    for n in an.thread_counts() {
        let key = CellKey::new(m, strat, opt, n);
        let Some(cell) = an.cells.get(&key) else { continue };
        match an.memory(&key, &o) {
            Some(e) => pts.push(PlotPoint {
                x: n as f64,
                y: e.value / GIB,
                lo: e.lo / GIB,
                hi: e.hi / GIB,
                hollow: cell.oversubscribed,
                grey: cell.noisy > 0,
                flagged: false,
            }),
            None if !cell.not_ok.is_empty() => skipped.push(n.to_string()),
            None => {}
        }
    }
    (pts, skipped)
}
