//! The hybrid figure and table: speedup, efficiency, and the shares of the wall time spent
//! communicating and waiting for other ranks, against the total cores (ranks x threads per
//! rank), one line per rank count, for every (model, strategy, opt level) a campaign ran
//! over several ranks ([`crate::analysis::hybrid`]). Written by `figures` as
//! `fig_hybrid.png/.svg` and shown by `report` in its own section; the paper's figures never
//! include these runs.
//!
//! Communication and waiting are separate panels and columns: waiting for a slower rank is
//! imbalance, not the cost of the exchange. Campaigns that did not measure the waiting apart
//! (CSV schema 4) show their exchange labelled as including the waiting, and the waiting as
//! not measured.

use super::plot::{series_colour, Line, Panel, PlotPoint};
use crate::analysis::hybrid::{HybridAnalysis, HybridPoint};
use crate::analysis::stats::{tag, Estimate};
use mpm_core::Strategy;

/// Footnote of the hybrid figure.
pub const FOOTNOTE: &str =
    "Speedup T(1 rank x 1 thread) / T(R x T), efficiency = speedup / (R x T) cores; medians, 95 % bootstrap bars. \
     Hollow: more workers than cores or ranks sharing CPUs (time sharing). Grey: busy host.";

/// What the communication and waiting panels and columns show: footnote lines of the
/// figure, sentences of the report.
pub const EXCHANGE_NOTES: [&str; 2] = [
    "Communication: exchange seconds without the waiting (mpm run --split-wait), of the rank that spent the most, \
     in % of the wall time.",
    "Waiting for other ranks: at a barrier before each exchange operation (imbalance, not the exchange's cost), of \
     the rank that waited most. Not measured before CSV schema 5, whose exchange includes it.",
];

/// The footnote lines of the hybrid figure: [`FOOTNOTE`] and [`EXCHANGE_NOTES`].
pub fn footnotes() -> Vec<String> {
    std::iter::once(FOOTNOTE).chain(EXCHANGE_NOTES).map(String::from).collect()
}

/// What a panel of the hybrid figure shows.
#[derive(Clone, Copy, PartialEq, Eq)]
enum Metric {
    Speedup,
    Efficiency,
    /// Communication seconds over the wall time, in percent (the exchange with the waiting
    /// in it where that was not measured apart).
    Communication,
    /// Seconds waiting for other ranks over the wall time, in percent.
    Waiting,
}

/// The panels of one combination, in column order.
const METRICS: [Metric; 4] = [Metric::Speedup, Metric::Efficiency, Metric::Communication, Metric::Waiting];

impl Metric {
    /// Its name in `points.csv` (the panel's column): the exchange of a point whose waiting
    /// was not measured apart is named as including it.
    fn name(self, p: &HybridPoint) -> &'static str {
        match self {
            Metric::Speedup => "speedup",
            Metric::Efficiency => "efficiency",
            Metric::Communication if p.comm_includes_wait => "exchange_incl_wait_percent",
            Metric::Communication => "communication_percent",
            Metric::Waiting => "waiting_percent",
        }
    }
}

/// Every value the hybrid figure draws, in panel order: the point, the metric's name in
/// `points.csv`, and the value with its 95 % interval (`value, lo, hi`).
pub fn drawn(h: &HybridAnalysis) -> Vec<(&HybridPoint, &'static str, (f64, f64, f64))> {
    let mut out = Vec::new();
    for (model, strategy, opt) in h.combos() {
        for metric in METRICS {
            for ranks in h.rank_counts() {
                for p in h.line(model, strategy, &opt, ranks) {
                    if let Some(v) = value(p, metric) {
                        out.push((p, metric.name(p), v));
                    }
                }
            }
        }
    }
    out
}

fn value(p: &HybridPoint, m: Metric) -> Option<(f64, f64, f64)> {
    let of = |e: Option<Estimate>| e.map(|e| (e.value, e.lo, e.hi));
    let percent = |f: Option<f64>| f.map(|f| (100.0 * f, 100.0 * f, 100.0 * f));
    match m {
        Metric::Speedup => of(p.speedup),
        Metric::Efficiency => of(p.efficiency),
        Metric::Communication => percent(p.comm_frac),
        Metric::Waiting => percent(p.wait_frac),
    }
}

/// Whether a combination has points whose waiting was not measured apart (their
/// communication includes it: rows before CSV schema 5).
fn wait_not_measured(h: &HybridAnalysis, model: u32, strategy: Strategy, opt: &str) -> bool {
    h.points
        .iter()
        .any(|p| p.key.model == model && p.key.strategy == strategy && p.key.opt_level == opt && p.comm_includes_wait)
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
                    Some(PlotPoint {
                        x: p.cores() as f64,
                        y,
                        lo,
                        hi,
                        hollow: p.oversubscribed,
                        grey: p.noisy,
                        flagged: false,
                    })
                })
                .collect(),
        })
        .collect();
    let top = lines.iter().flat_map(|l| l.points.iter().map(|p| p.hi)).fold(0.0f64, f64::max);
    let max_cores = h.points.iter().map(HybridPoint::cores).max().unwrap_or(1) as f64;
    let old = wait_not_measured(h, model, strategy, opt);
    let (what, y_desc, y_max, ideal, flat) = match metric {
        Metric::Speedup => ("speedup", "Speedup T1/T", (top * 1.1).max(max_cores), Some(1.0), false),
        Metric::Efficiency => ("efficiency", "Efficiency (speedup / cores)", (top * 1.1).max(1.2), Some(1.0), true),
        Metric::Communication if old => {
            ("exchange incl. waiting", "Exchange incl. waiting, % of wall time", (top * 1.2).max(10.0), None, false)
        }
        Metric::Communication => ("communication", "Communication, % of wall time", (top * 1.2).max(10.0), None, false),
        Metric::Waiting => {
            ("waiting for other ranks", "Waiting for other ranks, % of wall time", (top * 1.2).max(10.0), None, false)
        }
    };
    let notes = if lines.iter().all(|l| l.points.is_empty()) {
        vec![if matches!(metric, Metric::Waiting) && old { "not measured (before CSV schema 5)" } else { "no ok runs" }
            .into()]
    } else {
        vec![]
    };
    Panel {
        title: format!("Model{model} {} {}: {what}", tag(strategy), opt.to_uppercase()),
        y_desc: y_desc.into(),
        x_desc: "Total cores (ranks x threads per rank)".into(),
        x_max: max_cores + 1.0,
        y_max,
        ideal,
        ideal_flat: flat,
        notes,
        lines,
    }
}

/// The panels (a row of speedup, efficiency, communication share and waiting share per
/// combination) and the grid (rows, columns). Empty when the analysis has no point.
pub fn panels(h: &HybridAnalysis) -> (Vec<Panel>, (usize, usize)) {
    let combos = h.combos();
    let panels: Vec<Panel> = combos.iter().flat_map(|(m, s, o)| METRICS.map(|k| panel(h, *m, *s, o, k))).collect();
    (panels, (combos.len(), METRICS.len()))
}

/// Figure size for `rows` rows of panels.
pub fn size(rows: usize) -> (u32, u32) {
    (1900, 184 + 420 * rows.max(1) as u32)
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
        "communication (% of wall)",
        "waiting for other ranks (% of wall)",
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
                p.comm_frac.map_or("-".into(), |f| {
                    let with = if p.comm_includes_wait { " (incl. waiting)" } else { "" };
                    format!("{:.1} %{with}", 100.0 * f)
                }),
                match (p.key.ranks, p.wait_frac) {
                    (1, _) => "- (1 rank)".into(),
                    (_, Some(f)) => format!("{:.1} %", 100.0 * f),
                    (_, None) => "not measured".into(),
                },
                p.comm_bytes_per_step.map_or("-".into(), |b| format!("{:.2} MiB", b / 1048576.0)),
                p.memory_sum_bytes.map_or("-".into(), |b| format!("{:.0} MiB", b / (1u64 << 20) as f64)),
                p.reps.to_string(),
            ]
        })
        .collect();
    (head, rows)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::analysis::stats::StatsOptions;
    use crate::campaign::plan::preset::OptLevel;
    use crate::campaign::store::record::{Row, Status};

    /// Model 3, DD, one rank (the base) and two ranks whose exchange took `comm` of the
    /// wall time, with the waiting `wait` measured apart or not (a schema-4 row).
    fn analysis(comm: f64, wait: Option<f64>) -> HybridAnalysis {
        let row = |ranks: usize, comm: f64, wait: Option<f64>| {
            let mut run = crate::campaign::plan::matrix::PlannedRun::taylor(
                3,
                Strategy::DomainDecomposition,
                OptLevel::O3,
                1,
                10,
            );
            run.spec.ranks = ranks;
            let mut r = Row::planned(run);
            let f = r.measured_mut();
            f.timing.steady_s_per_step = Some(0.2 / ranks as f64);
            f.communication.comm_frac = Some(comm);
            f.communication.wait_frac = wait;
            f.communication.wait_s_per_step = wait.map(|w| 0.2 * w);
            r.outcome.status = Status::Ok;
            r
        };
        HybridAnalysis::from_rows(&[row(1, 0.0, None)], &[row(2, comm, wait)], None, &StatsOptions::default())
    }

    /// The table's cells of the communication and waiting columns, per configuration.
    fn exchange_cells(h: &HybridAnalysis) -> Vec<(String, String)> {
        let (head, rows) = table(h);
        let at = |name: &str| head.iter().position(|c| c.starts_with(name)).unwrap();
        let (c, w) = (at("communication"), at("waiting for other ranks"));
        rows.iter().map(|r| (r[c].clone(), r[w].clone())).collect()
    }

    /// Measured apart: the communication and the waiting in their own columns and panels.
    #[test]
    fn communication_and_waiting_are_shown_apart() {
        let h = analysis(0.031, Some(0.062));
        let cells = exchange_cells(&h);
        assert_eq!(cells, [("0.0 %".into(), "- (1 rank)".into()), ("3.1 %".into(), "6.2 %".into())]);
        let (panels, grid) = panels(&h);
        assert_eq!(grid, (1, 4));
        assert_eq!(panels[2].title, "Model3 DD O3: communication");
        assert_eq!(panels[3].title, "Model3 DD O3: waiting for other ranks");
        let two = |p: &Panel| p.lines.iter().find(|l| l.label == "2 ranks").unwrap().points.clone();
        assert!((two(&panels[2])[0].y - 3.1).abs() < 1e-12);
        assert!((two(&panels[3])[0].y - 6.2).abs() < 1e-12);
        assert!(panels[3].notes.is_empty());
    }

    /// A schema-4 campaign (waiting not measured): its exchange is labelled as including the
    /// waiting, and the waiting says "not measured", never 0.
    #[test]
    fn waiting_not_measured_is_said_not_zero() {
        let h = analysis(0.128, None);
        assert!(h.points.iter().any(|p| p.comm_includes_wait));
        let cells = exchange_cells(&h);
        assert_eq!(
            cells,
            [("0.0 %".into(), "- (1 rank)".into()), ("12.8 % (incl. waiting)".into(), "not measured".into())]
        );
        let (panels, _) = panels(&h);
        assert_eq!(panels[2].title, "Model3 DD O3: exchange incl. waiting");
        assert!(panels[3].lines.iter().all(|l| l.points.is_empty()));
        assert_eq!(panels[3].notes, ["not measured (before CSV schema 5)"]);
    }
}
