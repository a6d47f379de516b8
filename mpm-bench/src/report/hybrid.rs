//! The hybrid figure and table: speedup, efficiency and the exchange's share of a step
//! against the total cores (ranks x threads per rank), one line per rank count, for every
//! (model, strategy, opt level) a campaign ran over several ranks
//! ([`crate::analysis::hybrid`]). Written by `figures` as `fig_hybrid.png/.svg` and shown by
//! `report` in its own section; the paper's figures never include these runs.

use super::plot::{series_colour, Line, Panel, PlotPoint};
use crate::analysis::hybrid::{HybridAnalysis, HybridPoint};
use crate::analysis::stats::{tag, Estimate};
use mpm_core::Strategy;

/// Footnote of the hybrid figure.
pub const FOOTNOTE: &str =
    "Speedup T(1 rank x 1 thread) / T(R x T), efficiency = speedup / (R x T) cores; medians, 95 % bootstrap bars. \
     Hollow: more workers than cores or ranks sharing CPUs (time sharing). Grey: busy host.";

/// What a panel of the hybrid figure shows.
#[derive(Clone, Copy)]
enum Metric {
    Speedup,
    Efficiency,
    /// Exchange seconds over the wall time, in percent.
    CommShare,
}

fn value(p: &HybridPoint, m: Metric) -> Option<(f64, f64, f64)> {
    let of = |e: Option<Estimate>| e.map(|e| (e.value, e.lo, e.hi));
    match m {
        Metric::Speedup => of(p.speedup),
        Metric::Efficiency => of(p.efficiency),
        Metric::CommShare => p.comm_frac.map(|f| (100.0 * f, 100.0 * f, 100.0 * f)),
    }
}

/// Legend label of a line: `1 rank`, `2 ranks`.
pub fn ranks_label(ranks: usize) -> String {
    if ranks == 1 {
        "1 rank".into()
    } else {
        format!("{ranks} ranks")
    }
}

fn panel(h: &HybridAnalysis, model: u32, strategy: Strategy, opt: &str, metric: Metric) -> Panel {
    let ranks = h.rank_counts();
    let lines: Vec<Line> = ranks
        .iter()
        .enumerate()
        .map(|(i, &r)| Line {
            label: ranks_label(r),
            colour: series_colour(i),
            marker: i,
            dashed: false,
            points: h
                .line(model, strategy, opt, r)
                .into_iter()
                .filter_map(|p| {
                    let (y, lo, hi) = value(p, metric)?;
                    Some(PlotPoint { x: p.cores() as f64, y, lo, hi, hollow: p.oversubscribed, grey: p.noisy })
                })
                .collect(),
        })
        .collect();
    let top = lines.iter().flat_map(|l| l.points.iter().map(|p| p.hi)).fold(0.0f64, f64::max);
    let max_cores = h.points.iter().map(HybridPoint::cores).max().unwrap_or(1) as f64;
    let (what, y_desc, y_max, ideal, flat) = match metric {
        Metric::Speedup => ("speedup", "Speedup T1/T", (top * 1.1).max(max_cores), Some(1.0), false),
        Metric::Efficiency => ("efficiency", "Efficiency (speedup / cores)", (top * 1.1).max(1.2), Some(1.0), true),
        Metric::CommShare => ("exchange", "Exchange, % of wall time", (top * 1.2).max(10.0), None, false),
    };
    Panel {
        title: format!("Model{model} {} {}: {what}", tag(strategy), opt.to_uppercase()),
        y_desc: y_desc.into(),
        x_desc: "Total cores (ranks x threads per rank)".into(),
        x_max: max_cores + 1.0,
        y_max,
        ideal,
        ideal_flat: flat,
        notes: if lines.iter().all(|l| l.points.is_empty()) { vec!["no ok runs".into()] } else { vec![] },
        lines,
    }
}

/// The panels (a row of speedup, efficiency and exchange share per combination) and the
/// grid (rows, columns). Empty when the analysis has no point.
pub fn panels(h: &HybridAnalysis) -> (Vec<Panel>, (usize, usize)) {
    let combos = h.combos();
    let panels: Vec<Panel> = combos
        .iter()
        .flat_map(|(m, s, o)| [Metric::Speedup, Metric::Efficiency, Metric::CommShare].map(|k| panel(h, *m, *s, o, k)))
        .collect();
    (panels, (combos.len(), 3))
}

/// Figure size for `rows` rows of panels.
pub fn size(rows: usize) -> (u32, u32) {
    (1500, 140 + 420 * rows.max(1) as u32)
}

/// Title of the hybrid figure.
pub const TITLE: &str = "Hybrid MPI x threads: speedup against total cores";

/// The table of every configuration: head and rows.
pub fn table(h: &HybridAnalysis) -> (Vec<String>, Vec<Vec<String>>) {
    let head = [
        "configuration",
        "ranks x threads",
        "cores",
        "time per step",
        "speedup",
        "efficiency",
        "exchange share",
        "bytes sent per step",
        "memory (sum over ranks)",
        "reps",
    ]
    .map(String::from)
    .to_vec();
    let rows = h
        .points
        .iter()
        .map(|p| {
            let flag = if p.oversubscribed { " *" } else { "" };
            vec![
                format!("Model{} {} {}", p.key.model, tag(p.key.strategy), p.key.opt_level.to_uppercase()),
                format!("{} x {}{flag}", p.key.ranks, p.key.threads),
                p.cores().to_string(),
                format!("{} ms", p.time.scale(1e3).show(2)),
                p.speedup.map_or("-".into(), |e| e.show(2)),
                p.efficiency.map_or("-".into(), |e| e.show(2)),
                p.comm_frac.map_or("-".into(), |f| format!("{:.1} %", 100.0 * f)),
                p.comm_bytes_per_step.map_or("-".into(), |b| format!("{:.2} MB", b / 1e6)),
                p.memory_sum_bytes.map_or("-".into(), |b| format!("{:.0} MiB", b / (1u64 << 20) as f64)),
                p.reps.to_string(),
            ]
        })
        .collect();
    (head, rows)
}
