//! Every scatter strategy side by side: the figure `fig_strategies` of `mpm-bench figures`
//! (speedup, efficiency and peak memory against threads, one row of panels per model, one
//! line per strategy; drawn when a campaign ran a strategy beyond the paper's two, e.g. the
//! `strategies` preset) and the report's section with the measured choice of strategy per
//! model and thread count ([`crate::analysis::strategies`]).

use super::doc::{Block, Section};
use super::plot::{series_colour, write_png_svg, Line, Panel, PlotPoint};
use super::points::{memory_points, plot_point, Metric};
use super::sets::Set;
use crate::analysis::stats::{tag, Analysis, Stage};
use crate::analysis::strategies::{self as cmp, CHOICE_HEAD, NEW};
use anyhow::Result;
use mpm_core::Strategy;
use std::path::{Path, PathBuf};

/// File stem of the figure.
pub const STEM: &str = "fig_strategies";

/// Title of the figure.
pub const TITLE: &str = "Every scatter strategy: speedup, efficiency and peak memory vs threads (O3)";

/// Whether `an` has rows of a strategy beyond the paper's (the figure is drawn only then, so
/// that a campaign of the paper's protocol gets exactly the paper's figures).
pub fn wanted(an: &Analysis) -> bool {
    an.cells.keys().any(|k| NEW.contains(&k.strategy))
}

/// Which of the three panels of a model.
#[derive(Clone, Copy)]
enum Kind {
    Speedup,
    Efficiency,
    Memory,
}

/// The points of `s` on model `m` for one panel (memory in MiB).
fn points(an: &Analysis, m: u32, s: Strategy, kind: Kind) -> Vec<PlotPoint> {
    if let Kind::Memory = kind {
        let gib_to_mib = |p: PlotPoint| PlotPoint { y: p.y * 1024.0, lo: p.lo * 1024.0, hi: p.hi * 1024.0, ..p };
        return memory_points(an, m, s, "o3").0.into_iter().map(gib_to_mib).collect();
    }
    let metric = if let Kind::Speedup = kind { Metric::Speedup } else { Metric::Efficiency };
    an.series(m, s, "o3", Stage::Total).into_iter().filter_map(|p| plot_point(p, metric)).collect()
}

/// One panel of model `m`: a line per strategy with points (serial in the memory panel only).
fn panel(an: &Analysis, m: u32, kind: Kind, x_max: f64) -> Panel {
    let lines: Vec<Line> = Strategy::ALL
        .iter()
        .enumerate()
        .filter(|(_, s)| s.is_parallel() || matches!(kind, Kind::Memory))
        .map(|(i, &s)| Line {
            label: tag(s),
            colour: series_colour(i),
            marker: i % 4,
            dashed: false,
            points: points(an, m, s, kind),
        })
        .filter(|l| !l.points.is_empty())
        .collect();
    // The axes follow the points (the memory's intervals too); a wide interval of a ratio
    // with few processes runs off the panel rather than flattening every line.
    let top = |f: fn(&PlotPoint) -> f64| lines.iter().flat_map(|l| l.points.iter().map(f)).fold(0.0f64, f64::max);
    let (top, top_hi) = (top(|p| p.y), top(|p| p.hi));
    let (y_desc, y_max, ideal, flat) = match kind {
        Kind::Speedup => ("Speedup T1/Tn", (top * 1.3).max(x_max - 1.0).ceil(), Some(1.0), false),
        Kind::Efficiency => ("Efficiency (speedup / threads)", (top * 1.3).max(1.2), Some(1.0), true),
        Kind::Memory => ("Peak resident memory (MiB)", (top_hi * 1.3).max(1.0), None, false),
    };
    let what = match kind {
        Kind::Speedup => "speedup",
        Kind::Efficiency => "efficiency",
        Kind::Memory => "peak memory",
    };
    let notes = if lines.is_empty() { vec![format!("no ok O3 runs of Model{m}")] } else { Vec::new() };
    Panel {
        ideal,
        ideal_flat: flat,
        ..Panel::of_threads(format!("Model{m}, {what}"), y_desc.into(), x_max, y_max, lines, notes)
    }
}

/// The panels, model by model: speedup, efficiency, peak memory.
pub fn panels(an: &Analysis) -> Vec<Panel> {
    let mut models = an.models();
    if models.is_empty() {
        models = vec![1];
    }
    let x_max = (an.thread_counts().into_iter().max().unwrap_or(8) as f64 + 1.0).max(3.0);
    models
        .iter()
        .flat_map(|&m| [Kind::Speedup, Kind::Efficiency, Kind::Memory].map(|k| panel(an, m, k, x_max)))
        .collect()
}

/// Write the figure into `out` (`notes`: the campaign's footnotes). Returns the files.
pub fn write(out: &Path, an: &Analysis, notes: &[String]) -> Result<Vec<PathBuf>> {
    let panels = panels(an);
    let rows = panels.len() / 3;
    let mut foot = vec![
        "Total step at O3; speedup and efficiency against the same strategy's 1-thread time (paired cells: within each process). Peak memory: VmHWM of the solver process."
            .to_string(),
    ];
    foot.extend(notes.iter().cloned());
    write_png_svg(out, STEM, (1800, 120 + 420 * rows as u32 + 22 * foot.len() as u32), TITLE, &panels, (rows, 3), &foot)
}

/// The report's section: per results set, the measured choice of strategy per model and
/// thread count, then the new strategies against DD and AE.
pub(super) fn section(sets: &[Set]) -> Section {
    let mut blocks = vec![Block::Para(
        "The fastest parallel strategy per model and thread count (total step at O3, real parallel points only: \
         more than one thread and not oversubscribed), with the next fastest; \"cannot tell\" where their \
         intervals overlap. Then block colouring and atomic adds against domain decomposition and array \
         expansion: efficiency, time per step and peak memory, with intervals."
            .into(),
    )];
    for set in sets {
        let rows = cmp::choice_rows(&set.analysis);
        if rows.is_empty() {
            blocks.push(Block::Para(format!("{}: no real parallel points at O3, no choice.", set.label)));
        } else {
            blocks.push(Block::Table {
                caption: format!("Measured choice on {}", set.label),
                head: CHOICE_HEAD.iter().map(|h| h.to_string()).collect(),
                rows,
            });
        }
        blocks.push(Block::List(cmp::lines(&set.analysis)));
    }
    Section { id: "strategies".into(), title: "Which strategy, measured".into(), blocks }
}
