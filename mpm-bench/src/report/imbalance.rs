//! The figure of `mpm-bench imbalance`: predicted work imbalance of uniform and balanced DD
//! cuts, and of block colouring, against the thread count.

use super::plot::{series_colour, write_png_svg, Line, Panel, PlotPoint};
use crate::campaign::measure::imbalance::{stem, ImbalanceReport, ImbalanceRow};
use anyhow::Result;
use std::path::{Path, PathBuf};

/// One line: the mean over the steps, the bar from the best to the worst step.
fn line(r: &ImbalanceReport, label: &str, i: usize, pick: fn(&ImbalanceRow) -> (f64, f64)) -> Line {
    let best = |t: usize| {
        r.samples
            .iter()
            .filter(|s| s.threads == t)
            .map(|s| [s.uniform, s.balanced, s.colour][i])
            .fold(f64::INFINITY, f64::min)
    };
    let points = r
        .rows
        .iter()
        .map(|row| {
            let (mean, max) = pick(row);
            PlotPoint {
                x: row.threads as f64,
                y: mean,
                lo: best(row.threads).min(mean),
                hi: max,
                hollow: false,
                grey: false,
                flagged: false,
            }
        })
        .collect();
    Line { label: label.to_string(), colour: series_colour(i), marker: i, dashed: false, points }
}

/// Write `imbalance-<scenario>-m<model>.{png,svg}` into `dir`.
pub fn write_figure(r: &ImbalanceReport, dir: &Path) -> Result<Vec<PathBuf>> {
    let lines = vec![
        line(r, "uniform cuts (dd)", 0, |w| (w.uniform_mean, w.uniform_max)),
        line(r, "balanced cuts (dd-balanced)", 1, |w| (w.balanced_mean, w.balanced_max)),
        line(r, "block colouring (colour)", 2, |w| (w.colour_mean, w.colour_max)),
    ];
    let y_top = r.rows.iter().map(|w| w.uniform_max.max(w.balanced_max).max(w.colour_max)).fold(1.0, f64::max);
    let x_max = r.rows.iter().map(|w| w.threads).max().unwrap_or(1) as f64;
    let panel = Panel {
        title: format!("{} {}", r.scenario, r.model_name),
        y_desc: "work imbalance (max / mean particles per patch)".into(),
        x_desc: "threads (patches)".into(),
        x_max: x_max + 0.5,
        y_max: (y_top * 1.1).max(1.2),
        ideal: Some(1.0),
        ideal_flat: true,
        lines,
        notes: r
            .rows
            .iter()
            .map(|w| format!("{} threads: uniform {}, balanced {}", w.threads, w.layout, w.balanced_layout))
            .collect(),
    };
    let notes = vec![
        format!(
            "Predicted from particle counts before each of {} steps of a serial run ({} particles); point = mean over the steps, bar = best to worst step.",
            r.steps, r.particles
        ),
        "Made by mpm-bench imbalance; no timing, so it holds on any machine.".to_string(),
    ];
    write_png_svg(
        dir,
        &stem(r),
        (1000, 720),
        "Work imbalance: DD uniform vs balanced cuts, block colouring",
        &[panel],
        (1, 1),
        &notes,
    )
}
