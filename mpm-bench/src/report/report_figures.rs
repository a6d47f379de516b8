//! The report's figures, machines overlaid (one line per machine, one panel per model): speedup
//! and efficiency, throughput and ns per particle-step, per strategy and optimisation level,
//! drawn as SVG text for the page.

use super::doc::Block;
use super::plot::{series_colour, svg_string, Line, Panel, PlotPoint};
use super::sets::{combos, strategy_opt_pairs, Set};
use crate::analysis::stats::{Point, Stage};
use anyhow::Result;
use mpm_core::Strategy;

/// What a row of panels shows.
#[derive(Clone, Copy, PartialEq, Eq)]
enum Metric {
    Speedup,
    Efficiency,
    /// Million particle-steps per second.
    Throughput,
    /// Nanoseconds per particle-step.
    NsPerParticleStep,
}

impl Metric {
    fn y_desc(self) -> &'static str {
        match self {
            Metric::Speedup => "Speedup (total)",
            Metric::Efficiency => "Efficiency (total)",
            Metric::Throughput => "M particle-steps/s",
            Metric::NsPerParticleStep => "ns per particle-step",
        }
    }

    /// (value, lo, hi) of a point with `particles` particles.
    fn of(self, p: &Point, particles: Option<u64>) -> Option<(f64, f64, f64)> {
        let per = |f: fn(f64, f64) -> f64| {
            let n = particles? as f64;
            let (a, b) = (f(p.time.lo, n), f(p.time.hi, n));
            Some((f(p.time.value, n), a.min(b), a.max(b)))
        };
        match self {
            Metric::Speedup => p.speedup.map(|e| (e.value, e.lo, e.hi)),
            Metric::Efficiency => p.efficiency.map(|e| (e.value, e.lo, e.hi)),
            Metric::Throughput => per(|t, n| n / t / 1e6),
            Metric::NsPerParticleStep => per(|t, n| t / n * 1e9),
        }
    }
}

/// One panel: `metric` of model `m`, one line per set.
fn panel(sets: &[Set], m: u32, strategy: Strategy, opt: &str, metric: Metric) -> Panel {
    let lines: Vec<Line> = sets
        .iter()
        .enumerate()
        .map(|(i, set)| Line {
            label: set.label.clone(),
            colour: series_colour(i),
            marker: i,
            dashed: false,
            points: set
                .analysis
                .series(m, strategy, opt, Stage::Total)
                .into_iter()
                .filter_map(|p| {
                    let parts = set.analysis.cells.get(&p.key).and_then(|c| c.particles);
                    let (y, lo, hi) = metric.of(p, parts)?;
                    Some(PlotPoint {
                        x: p.key.threads as f64,
                        y,
                        lo,
                        hi,
                        hollow: p.oversubscribed,
                        grey: p.noisy,
                        flagged: !p.flags.is_empty(),
                    })
                })
                .collect(),
        })
        .collect();
    let top = lines.iter().flat_map(|l| l.points.iter().map(|p| p.hi)).fold(0.0f64, f64::max);
    let max_threads = sets.iter().flat_map(|s| s.analysis.thread_counts()).max().unwrap_or(8) as f64;
    let (ideal, flat, floor) = match metric {
        Metric::Speedup => (Some(1.0), false, max_threads),
        Metric::Efficiency => (Some(1.0), true, 1.2),
        _ => (None, false, 0.0),
    };
    Panel {
        title: format!("Model{m}"),
        y_desc: metric.y_desc().into(),
        x_desc: "Number of threads".into(),
        x_max: (max_threads + 1.0).max(9.0),
        y_max: (top * 1.1).max(floor).max(1e-9),
        ideal,
        ideal_flat: flat,
        lines,
        notes: vec![],
    }
}

/// One figure per (strategy, opt) with a row of panels per metric.
fn figures(sets: &[Set], metrics: [Metric; 2], what: &str, file: &str) -> Result<Vec<Block>> {
    let mut out = Vec::new();
    for (strategy, opt) in strategy_opt_pairs() {
        let models: Vec<u32> =
            combos(sets, true).into_iter().filter(|c| c.1 == strategy && c.2 == opt).map(|c| c.0).collect();
        if models.is_empty() {
            continue;
        }
        let panels: Vec<Panel> = metrics
            .iter()
            .flat_map(|&k| models.iter().map(move |&m| (m, k)))
            .map(|(m, k)| panel(sets, m, strategy, opt, k))
            .collect();
        let cols = models.len();
        let title = format!("{what} of {} ({}), total step", strategy.label(), opt.to_uppercase());
        let svg = svg_string(
            (380 * cols as u32 + 40, 140 + 2 * 380),
            &title,
            &panels,
            (2, cols),
            &["Hollow markers: more threads than cores (time sharing). Grey: measured on a busy host. Bars: 95 % bootstrap intervals."
                .into()],
        )?;
        out.push(Block::Figure { title, file: format!("{file}-{strategy}-{opt}.svg"), svg });
    }
    Ok(out)
}

/// Speedup (top row) and efficiency (bottom row), machines overlaid.
pub(super) fn scaling_figures(sets: &[Set]) -> Result<Vec<Block>> {
    figures(sets, [Metric::Speedup, Metric::Efficiency], "Speedup and efficiency", "scaling")
}

/// Throughput (top row) and ns per particle-step (bottom row), machines overlaid.
pub(super) fn throughput_figures(sets: &[Set]) -> Result<Vec<Block>> {
    figures(
        sets,
        [Metric::Throughput, Metric::NsPerParticleStep],
        "Throughput and time per particle-step",
        "throughput",
    )
}
