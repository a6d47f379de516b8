//! `mpm-bench figures`: the paper's Figures 7-14 (speedup and efficiency of AE and DD, at O3
//! and without optimisation) and a memory figure, regenerated from a campaign's runs.csv.
//!
//! Every figure has the paper's three panels, (a) total computation, (b) grid-node stage,
//! (c) particle stage, with the number of threads (0-9) on x and one line per model
//! (Model1-Model4). Points are medians over repetitions; bars are 95 % bootstrap intervals
//! of the ratio of medians ([`crate::stats`]); with a single repetition there are no bars
//! and the footnote says so. Oversubscribed points (more threads than usable cores) are
//! drawn hollow, joined by dotted segments, and the footnote names them: they are time
//! sharing, not scaling. Configurations without an `ok` run (e.g. skipped by the memory
//! guard) are absent, never drawn as zero. Text uses the DejaVu Sans compiled into the
//! program ([`mpm_cli::picture::register_fonts`]).
//!
//! Files: `fig07.{png,svg}` .. `fig14.{png,svg}`, `fig_memory.{png,svg}` and a `README.md`
//! saying which campaign and command made them.

use crate::stats::{load_campaign, Analysis, Campaign, CellKey, Point, Stage, StatsOptions};
use anyhow::{anyhow, Context, Result};
use mpm_cli::picture::register_fonts;
use plotters::coord::Shift;
use plotters::prelude::*;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

/// Regenerate the paper's Figures 7-14 (and a memory figure) from a campaign.
///
/// Writes fig07..fig14 and fig_memory as PNG and SVG, plus a README.md naming the campaign
/// and the command. Speedup is T1/Tn and efficiency speedup/n (paper Eqs. 19-20), from
/// medians over repetitions with 95 % bootstrap interval bars; oversubscribed points are
/// hollow; skipped configurations are absent.
#[derive(clap::Args, Debug, Clone)]
pub struct FiguresArgs {
    /// A campaign folder (holding runs.csv) or a folder containing campaigns (e.g. results/
    /// or results/FINGERPRINT/): then the newest campaign (by runs.csv modification
    /// time) is used and named.
    #[arg(long)]
    pub results: PathBuf,
    /// Output folder (created if needed).
    #[arg(long, default_value = "paper-figures")]
    pub out: PathBuf,
    /// Pinning policy to plot when the campaign has several (default: close, else the first).
    #[arg(long)]
    pub pin: Option<String>,
}

/// Speedup or efficiency.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Metric {
    /// `T1 / Tn`.
    Speedup,
    /// `speedup / n`.
    Efficiency,
}

/// One of the paper's Figures 7-14.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct FigureSpec {
    /// Figure number (7-14).
    pub number: u32,
    /// `ae` or `dd`.
    pub strategy: &'static str,
    /// `o3` or `o0`.
    pub opt_level: &'static str,
    /// What is plotted.
    pub metric: Metric,
}

impl FigureSpec {
    /// File stem, `fig07` .. `fig14`.
    pub fn stem(&self) -> String {
        format!("fig{:02}", self.number)
    }

    /// The figure's title.
    pub fn title(&self) -> String {
        let what = match self.metric {
            Metric::Speedup => "Speedup",
            Metric::Efficiency => "Efficiency",
        };
        let strat = if self.strategy == "ae" { "array expansion (AE)" } else { "domain decomposition (DD)" };
        let opt = if self.opt_level == "o3" { "with O3 optimisation" } else { "without optimisation" };
        format!("Fig. {}  {what} of {strat} {opt}", self.number)
    }
}

/// The paper's Figures 7-14.
pub const PAPER_FIGURES: [FigureSpec; 8] = [
    FigureSpec { number: 7, strategy: "ae", opt_level: "o3", metric: Metric::Speedup },
    FigureSpec { number: 8, strategy: "ae", opt_level: "o3", metric: Metric::Efficiency },
    FigureSpec { number: 9, strategy: "ae", opt_level: "o0", metric: Metric::Speedup },
    FigureSpec { number: 10, strategy: "ae", opt_level: "o0", metric: Metric::Efficiency },
    FigureSpec { number: 11, strategy: "dd", opt_level: "o3", metric: Metric::Speedup },
    FigureSpec { number: 12, strategy: "dd", opt_level: "o3", metric: Metric::Efficiency },
    FigureSpec { number: 13, strategy: "dd", opt_level: "o0", metric: Metric::Speedup },
    FigureSpec { number: 14, strategy: "dd", opt_level: "o0", metric: Metric::Efficiency },
];

/// Size of a figure in pixels.
pub const FIGURE_SIZE: (u32, u32) = (1800, 640);

/// Colour of model `m` (1-4); shared with the report's figures.
pub fn model_colour(m: u32) -> RGBColor {
    match m {
        1 => RGBColor(31, 119, 180),
        2 => RGBColor(214, 39, 40),
        3 => RGBColor(44, 160, 44),
        4 => RGBColor(0, 0, 0),
        _ => RGBColor(148, 103, 189),
    }
}

/// Colour of the `i`-th of several lines (machines in the report).
pub fn series_colour(i: usize) -> RGBColor {
    const C: [RGBColor; 6] = [
        RGBColor(31, 119, 180),
        RGBColor(214, 39, 40),
        RGBColor(44, 160, 44),
        RGBColor(0, 0, 0),
        RGBColor(148, 103, 189),
        RGBColor(255, 127, 14),
    ];
    C[i % C.len()]
}

/// Turn a plotters error into an anyhow error.
pub(crate) fn pe<E: std::fmt::Display>(e: E) -> anyhow::Error {
    anyhow!("drawing failed: {e}")
}

/// A point to plot: x, y, interval, hollow.
#[derive(Clone, Copy, Debug)]
pub struct PlotPoint {
    /// Threads.
    pub x: f64,
    /// Value.
    pub y: f64,
    /// Interval (equal to `y` when degenerate).
    pub lo: f64,
    /// Interval.
    pub hi: f64,
    /// Drawn hollow (oversubscribed).
    pub hollow: bool,
}

/// One line of a panel.
#[derive(Clone, Debug)]
pub struct Line {
    /// Legend label.
    pub label: String,
    /// Colour.
    pub colour: RGBColor,
    /// Marker: 0 circle, 1 triangle, 2 square, 3 diamond.
    pub marker: usize,
    /// Dashed (e.g. O0 lines of the memory figure).
    pub dashed: bool,
    /// Points by ascending x.
    pub points: Vec<PlotPoint>,
}

/// A panel: title, axes and lines.
#[derive(Clone, Debug)]
pub struct Panel {
    /// Title above the panel.
    pub title: String,
    /// y-axis label.
    pub y_desc: String,
    /// x-axis label.
    pub x_desc: String,
    /// x range.
    pub x_max: f64,
    /// y range.
    pub y_max: f64,
    /// The ideal line: `Some(k)` draws `y = k x` (speedup, k = 1) or `y = k` with
    /// `ideal_flat` (efficiency), dashed.
    pub ideal: Option<f64>,
    /// The ideal line is horizontal.
    pub ideal_flat: bool,
    /// Lines.
    pub lines: Vec<Line>,
    /// Text lines written in the panel's lower right corner.
    pub notes: Vec<String>,
}

fn draw_marker<DB: DrawingBackend>(
    chart: &mut ChartContext<
        '_,
        DB,
        Cartesian2d<plotters::coord::types::RangedCoordf64, plotters::coord::types::RangedCoordf64>,
    >,
    p: &PlotPoint,
    line: &Line,
) -> Result<()> {
    // Hollow = the filled shape in the line's colour with a smaller white one on top (the
    // triangle marker of plotters is always filled, so outlines are made this way).
    let at = (p.x, p.y);
    let layers: Vec<(i32, ShapeStyle)> =
        if p.hollow { vec![(7, line.colour.filled()), (4, WHITE.filled())] } else { vec![(6, line.colour.filled())] };
    for (s, style) in layers {
        match line.marker % 4 {
            0 => chart.draw_series(std::iter::once(Circle::new(at, s, style))).map_err(pe)?,
            1 => chart.draw_series(std::iter::once(TriangleMarker::new(at, s + 2, style))).map_err(pe)?,
            2 => {
                let r = s - 1;
                chart
                    .draw_series(std::iter::once(EmptyElement::at(at) + Rectangle::new([(-r, -r), (r, r)], style)))
                    .map_err(pe)?
            }
            _ => {
                let r = s + 1;
                let pts = vec![(0, -r), (r, 0), (0, r), (-r, 0)];
                chart.draw_series(std::iter::once(EmptyElement::at(at) + Polygon::new(pts, style))).map_err(pe)?
            }
        };
    }
    Ok(())
}

/// Draw one panel into `area`.
pub fn draw_panel<DB: DrawingBackend>(area: &DrawingArea<DB, Shift>, panel: &Panel) -> Result<()> {
    let mut chart = ChartBuilder::on(area)
        .caption(&panel.title, ("sans-serif", 20))
        .margin(12)
        .x_label_area_size(42)
        .y_label_area_size(58)
        .build_cartesian_2d(0f64..panel.x_max, 0f64..panel.y_max)
        .map_err(pe)?;
    let x_ticks = panel.x_max.round() as usize + 1;
    // Enough decimals that the ~10 tick labels differ.
    let decimals = if panel.y_max > 2.0 { 0 } else { (-(panel.y_max / 10.0).log10()).ceil().max(1.0) as usize };
    chart
        .configure_mesh()
        .x_labels(x_ticks.min(12))
        .x_label_formatter(&|x| format!("{x:.0}"))
        .y_label_formatter(&|y| format!("{y:.*}", decimals))
        .x_desc(&panel.x_desc)
        .y_desc(&panel.y_desc)
        .label_style(("sans-serif", 15))
        .axis_desc_style(("sans-serif", 16))
        .light_line_style(WHITE.mix(0.0))
        .bold_line_style(BLACK.mix(0.12))
        .draw()
        .map_err(pe)?;
    if let Some(k) = panel.ideal {
        let pts: Vec<(f64, f64)> = if panel.ideal_flat {
            vec![(0.0, k), (panel.x_max, k)]
        } else {
            let end = (panel.y_max / k).min(panel.x_max);
            vec![(0.0, 0.0), (end, end * k)]
        };
        chart.draw_series(DashedLineSeries::new(pts, 8, 6, BLACK.mix(0.6).stroke_width(1))).map_err(pe)?;
    }
    for line in &panel.lines {
        let colour = line.colour;
        // Segments: solid between real points, dotted when either end is hollow.
        for w in line.points.windows(2) {
            let seg = vec![(w[0].x, w[0].y), (w[1].x, w[1].y)];
            if w[0].hollow || w[1].hollow || line.dashed {
                let (size, gap) = if line.dashed && !(w[0].hollow || w[1].hollow) { (8, 5) } else { (3, 4) };
                chart.draw_series(DashedLineSeries::new(seg, size, gap, colour.stroke_width(2))).map_err(pe)?;
            } else {
                chart.draw_series(LineSeries::new(seg, colour.stroke_width(2))).map_err(pe)?;
            }
        }
        for p in &line.points {
            if p.hi > p.lo {
                chart
                    .draw_series(std::iter::once(ErrorBar::new_vertical(
                        p.x,
                        p.lo,
                        p.y,
                        p.hi,
                        colour.stroke_width(1),
                        8,
                    )))
                    .map_err(pe)?;
            }
            draw_marker(&mut chart, p, line)?;
        }
    }
    if !panel.notes.is_empty() {
        let (w, h) = area.dim_in_pixel();
        let k = panel.notes.len() as i32;
        for (i, n) in panel.notes.iter().enumerate() {
            area.draw(&Text::new(
                n.clone(),
                (w as i32 - 24, h as i32 - 64 - 20 * (k - 1 - i as i32)),
                ("sans-serif", 14).into_font().color(&BLACK.mix(0.8)).pos(plotters::style::text_anchor::Pos::new(
                    plotters::style::text_anchor::HPos::Right,
                    plotters::style::text_anchor::VPos::Bottom,
                )),
            ))
            .map_err(pe)?;
        }
    }
    Ok(())
}

/// A marker in pixel coordinates (the legend's), hollow or filled.
fn marker_px<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    at: (i32, i32),
    marker: usize,
    colour: RGBColor,
    hollow: bool,
) -> Result<()> {
    let layers: Vec<(i32, ShapeStyle)> =
        if hollow { vec![(7, colour.filled()), (4, WHITE.filled())] } else { vec![(6, colour.filled())] };
    let (x, y) = at;
    for (s, style) in layers {
        match marker % 4 {
            0 => area.draw(&Circle::new(at, s, style)).map_err(pe)?,
            1 => area.draw(&TriangleMarker::new(at, s + 2, style)).map_err(pe)?,
            2 => area.draw(&Rectangle::new([(x - s + 1, y - s + 1), (x + s - 1, y + s - 1)], style)).map_err(pe)?,
            _ => area
                .draw(&Polygon::new(vec![(x, y - s - 1), (x + s + 1, y), (x, y + s + 1), (x - s - 1, y)], style))
                .map_err(pe)?,
        }
    }
    Ok(())
}

/// A legend entry: label, (colour, marker, dashed) of a line, dashed sample.
type LegendItem = (String, Option<(RGBColor, usize, bool)>, bool);

/// One legend strip for the whole figure (under the title, so it never hides data): every
/// line label once, the ideal line, and the hollow-marker note when any point is hollow.
fn draw_legend<DB: DrawingBackend>(area: &DrawingArea<DB, Shift>, panels: &[Panel]) -> Result<()> {
    let font = ("sans-serif", 16).into_font();
    let mut seen: Vec<String> = Vec::new();
    let (w, h) = area.dim_in_pixel();
    let y = h as i32 / 2;
    let mut items: Vec<LegendItem> = Vec::new();
    if panels.iter().any(|p| p.ideal.is_some()) {
        items.push(("ideal".into(), None, true));
    }
    for l in panels.iter().flat_map(|p| &p.lines) {
        if !seen.contains(&l.label) {
            seen.push(l.label.clone());
            items.push((l.label.clone(), Some((l.colour, l.marker, l.dashed)), l.dashed));
        }
    }
    let hollow = panels.iter().any(|p| p.lines.iter().any(|l| l.points.iter().any(|q| q.hollow)));
    if hollow {
        items.push(("hollow, dotted: more threads than cores — time sharing, not scaling".into(), None, false));
    }
    let widths: Vec<i32> = items
        .iter()
        .map(|(t, _, _)| {
            44 + area
                .estimate_text_size(t, &TextStyle::from(font.clone()))
                .map(|s| s.0 as i32)
                .unwrap_or(9 * t.len() as i32)
                + 26
        })
        .collect();
    let total: i32 = widths.iter().sum();
    let mut x = ((w as i32 - total) / 2).max(10);
    for ((label, sym, dashed), wd) in items.iter().zip(widths) {
        match sym {
            Some((colour, marker, _)) => {
                let style = colour.stroke_width(2);
                if *dashed {
                    for k in 0..3 {
                        area.draw(&PathElement::new(vec![(x + 14 * k, y), (x + 14 * k + 8, y)], style)).map_err(pe)?;
                    }
                } else {
                    area.draw(&PathElement::new(vec![(x, y), (x + 36, y)], style)).map_err(pe)?;
                }
                marker_px(area, (x + 18, y), *marker, *colour, false)?;
            }
            None if label == "ideal" => {
                for k in 0..3 {
                    area.draw(&PathElement::new(
                        vec![(x + 14 * k, y), (x + 14 * k + 8, y)],
                        BLACK.mix(0.6).stroke_width(1),
                    ))
                    .map_err(pe)?;
                }
            }
            None => {
                marker_px(area, (x + 18, y), 0, RGBColor(110, 110, 110), true)?;
            }
        }
        area.draw(&Text::new(
            label.clone(),
            (x + 44, y),
            font.clone().color(&BLACK).pos(plotters::style::text_anchor::Pos::new(
                plotters::style::text_anchor::HPos::Left,
                plotters::style::text_anchor::VPos::Center,
            )),
        ))
        .map_err(pe)?;
        x += wd;
    }
    Ok(())
}

/// Draw a whole figure: a title strip, `panels` side by side (or `grid` rows x cols), and a
/// footnote strip.
pub fn draw_figure<DB: DrawingBackend>(
    root: &DrawingArea<DB, Shift>,
    title: &str,
    panels: &[Panel],
    grid: (usize, usize),
    footnotes: &[String],
) -> Result<()> {
    root.fill(&WHITE).map_err(pe)?;
    let (_, h) = root.dim_in_pixel();
    let foot_h = 12 + 22 * footnotes.len() as u32;
    let (top, rest) = root.split_vertically(76);
    let (body, foot) = rest.split_vertically(h.saturating_sub(76 + foot_h));
    let (title_area, legend_area) = top.split_vertically(40);
    title_area.titled(title, ("sans-serif", 24)).map_err(pe)?;
    draw_legend(&legend_area, panels)?;
    let areas = body.split_evenly(grid);
    for (a, p) in areas.iter().zip(panels) {
        draw_panel(a, p)?;
    }
    for (i, f) in footnotes.iter().enumerate() {
        foot.draw(&Text::new(f.clone(), (20, 4 + 22 * i as i32), ("sans-serif", 15).into_font().color(&BLACK)))
            .map_err(pe)?;
    }
    Ok(())
}

/// Draw a figure (title, panels in a grid, footnotes) to `<dir>/<stem>.png` and `.svg`.
pub fn write_png_svg(
    dir: &Path,
    stem: &str,
    size: (u32, u32),
    title: &str,
    panels: &[Panel],
    grid: (usize, usize),
    footnotes: &[String],
) -> Result<Vec<PathBuf>> {
    register_fonts();
    let png = dir.join(format!("{stem}.png"));
    let svg = dir.join(format!("{stem}.svg"));
    {
        let root = BitMapBackend::new(&png, size).into_drawing_area();
        draw_figure(&root, title, panels, grid, footnotes)?;
        root.present().map_err(pe).with_context(|| format!("cannot write {}", png.display()))?;
    }
    {
        let root = SVGBackend::new(&svg, size).into_drawing_area();
        draw_figure(&root, title, panels, grid, footnotes)?;
        root.present().map_err(pe).with_context(|| format!("cannot write {}", svg.display()))?;
    }
    Ok(vec![png, svg])
}

fn marker_of(model: u32) -> usize {
    (model as usize + 3) % 4
}

fn plot_point(p: &Point, metric: Metric) -> Option<PlotPoint> {
    let e = match metric {
        Metric::Speedup => p.speedup?,
        Metric::Efficiency => p.efficiency?,
    };
    Some(PlotPoint { x: p.key.threads as f64, y: e.value, lo: e.lo, hi: e.hi, hollow: p.oversubscribed })
}

/// The three panels of one of Figures 7-14.
pub fn paper_panels(an: &Analysis, spec: &FigureSpec) -> Vec<Panel> {
    let models = {
        let mut m = an.models();
        if m.is_empty() {
            m = vec![1, 2, 3, 4];
        }
        m
    };
    let max_threads = an.thread_counts().into_iter().max().unwrap_or(8) as f64;
    let x_max = (max_threads + 1.0).max(9.0);
    Stage::ALL
        .iter()
        .map(|&stage| {
            let lines: Vec<Line> = models
                .iter()
                .map(|&m| Line {
                    label: format!("Model{m}"),
                    colour: model_colour(m),
                    marker: marker_of(m),
                    dashed: false,
                    points: an
                        .series(m, spec.strategy, spec.opt_level, stage)
                        .into_iter()
                        .filter_map(|p| plot_point(p, spec.metric))
                        .collect(),
                })
                .collect();
            let top = lines.iter().flat_map(|l| l.points.iter().map(|p| p.hi)).fold(0.0f64, f64::max);
            let (y_max, y_desc, ideal, flat) = match spec.metric {
                Metric::Speedup => ((top * 1.1).max(8.0).ceil(), "Speedup T1/Tn", Some(1.0), false),
                Metric::Efficiency => ((top * 1.1).max(1.2), "Efficiency (speedup / threads)", Some(1.0), true),
            };
            let mut notes = Vec::new();
            if lines.iter().all(|l| l.points.is_empty()) {
                notes.push(format!(
                    "no ok runs of {} {} in this campaign",
                    spec.strategy.to_uppercase(),
                    spec.opt_level.to_uppercase()
                ));
            }
            Panel {
                title: stage.title().to_string(),
                y_desc: y_desc.into(),
                x_desc: "Number of threads".into(),
                x_max,
                y_max,
                ideal,
                ideal_flat: flat,
                lines,
                notes,
            }
        })
        .collect()
}

/// Footnotes common to the figures of a campaign.
pub fn footnotes(c: &Campaign, an: &Analysis) -> Vec<String> {
    let reps = an.max_reps();
    let bars = if reps >= 2 {
        format!(
            "Points: medians over up to {reps} repetitions; bars: 95 % bootstrap intervals of the ratio of medians."
        )
    } else {
        "Points: single repetitions (no interval: repeat runs with --reps to get error bars).".to_string()
    };
    let hollow = if an.any_oversubscribed() {
        " Hollow markers, dotted lines: more threads than cores — time sharing, not scaling."
    } else {
        ""
    };
    vec![
        format!("{bars}{hollow} Missing points: no ok run (e.g. skipped by the memory guard)."),
        format!(
            "Campaign {} on machine {} ({} rows, pinning '{}'); T1 = the same strategy on 1 thread.",
            c.id(),
            c.fingerprint(),
            c.rows.len(),
            an.pin_policy
        ),
    ]
}

/// Panels of the memory figure: one per model, AE and DD (solid O3, dashed O0).
pub fn memory_panels(an: &Analysis) -> Vec<Panel> {
    let o = StatsOptions::default();
    let mut models = an.models();
    if models.is_empty() {
        models = vec![1];
    }
    let max_threads = an.thread_counts().into_iter().max().unwrap_or(8) as f64;
    models
        .iter()
        .map(|&m| {
            let mut lines = Vec::new();
            let mut notes = Vec::new();
            let mut top = 0.0f64;
            for (si, strat) in ["ae", "dd"].into_iter().enumerate() {
                for opt in ["o3", "o0"] {
                    let mut pts = Vec::new();
                    let mut skipped = Vec::new();
                    for n in an.thread_counts() {
                        let key = CellKey::new(m, strat, opt, n);
                        let Some(cell) = an.cells.get(&key) else { continue };
                        match an.memory(&key, &o) {
                            Some(e) => pts.push(PlotPoint {
                                x: n as f64,
                                y: e.value / 1e9,
                                lo: e.lo / 1e9,
                                hi: e.hi / 1e9,
                                hollow: cell.oversubscribed,
                            }),
                            None if !cell.not_ok.is_empty() => skipped.push(n.to_string()),
                            None => {}
                        }
                    }
                    if !skipped.is_empty() {
                        notes.push(format!(
                            "{} {}: no run at {} thread(s) (skipped/failed)",
                            strat.to_uppercase(),
                            opt.to_uppercase(),
                            skipped.join(", ")
                        ));
                    }
                    if pts.is_empty() {
                        continue;
                    }
                    top = pts.iter().map(|p| p.hi).fold(top, f64::max);
                    let o0 = opt == "o0";
                    lines.push(Line {
                        label: format!("{} {}", strat.to_uppercase(), opt.to_uppercase()),
                        colour: match (si, o0) {
                            (0, false) => RGBColor(31, 119, 180),
                            (0, true) => RGBColor(120, 180, 230),
                            (_, false) => RGBColor(214, 39, 40),
                            (_, true) => RGBColor(255, 127, 14),
                        },
                        marker: si + 2 * o0 as usize,
                        dashed: o0,
                        points: pts,
                    });
                }
            }
            // GB, or MB for small models.
            let (unit, k) = if top < 1.0 { ("MB", 1e3) } else { ("GB", 1.0) };
            for l in &mut lines {
                for p in &mut l.points {
                    (p.y, p.lo, p.hi) = (p.y * k, p.lo * k, p.hi * k);
                }
            }
            Panel {
                title: format!("Model{m}"),
                y_desc: format!("Peak resident memory ({unit})"),
                x_desc: "Number of threads".into(),
                x_max: (max_threads + 1.0).max(9.0),
                y_max: (top * k * 1.6).max(0.05),
                ideal: None,
                ideal_flat: false,
                lines,
                notes,
            }
        })
        .collect()
}

/// Write Figures 7-14, the memory figure and the README into `out`. Returns the files.
pub fn write_all(c: &Campaign, an: &Analysis, out: &Path, command: &str) -> Result<Vec<PathBuf>> {
    std::fs::create_dir_all(out)
        .with_context(|| format!("cannot create the output folder {}: choose a writable --out", out.display()))?;
    let probe = out.join(".write-test");
    std::fs::write(&probe, b"")
        .with_context(|| format!("cannot write into {}: choose a writable --out", out.display()))?;
    let _ = std::fs::remove_file(&probe);
    let notes = footnotes(c, an);
    let mut files = Vec::new();
    for spec in &PAPER_FIGURES {
        let panels = paper_panels(an, spec);
        files.extend(write_png_svg(out, &spec.stem(), FIGURE_SIZE, &spec.title(), &panels, (1, 3), &notes)?);
    }
    let mem = memory_panels(an);
    let cols = mem.len().clamp(1, 2);
    let rows = mem.len().div_ceil(cols);
    let mut mem_notes = vec![
        "Peak resident memory (VmHWM of the solver process), median over repetitions. AE keeps one copy of the nodal arrays per thread; DD one sub-grid per patch (claims C2, C6).".to_string(),
    ];
    mem_notes.push(notes[1].clone());
    files.extend(write_png_svg(
        out,
        "fig_memory",
        (1400, 120 + 460 * rows as u32),
        "Peak memory vs threads: array expansion (AE) vs domain decomposition (DD)",
        &mem,
        (rows, cols),
        &mem_notes,
    )?);
    let readme = out.join("README.md");
    std::fs::write(&readme, readme_text(c, an, command))
        .with_context(|| format!("cannot write {}", readme.display()))?;
    files.push(readme);
    Ok(files)
}

fn readme_text(c: &Campaign, an: &Analysis, command: &str) -> String {
    let mut s = String::new();
    let _ = writeln!(s, "# Figures 7-14 of the paper, regenerated\n");
    let _ = writeln!(s, "Made from campaign `{}` on machine `{}`:", c.id(), c.fingerprint());
    let _ =
        writeln!(s, "`{}` ({} rows, pinning `{}`).\n", c.dir.join("runs.csv").display(), c.rows.len(), an.pin_policy);
    let _ = writeln!(s, "Command:\n\n```sh\n{command}\n```\n");
    if let Some(m) = &c.manifest {
        let _ = writeln!(
            s,
            "Machine: {}, {} socket(s), {} cores, {} PUs, {:.1} GiB; {}; {}.\n",
            m.machine.cpu_model,
            m.machine.packages,
            m.machine.cores,
            m.machine.pus,
            m.machine.memory_bytes as f64 / (1u64 << 30) as f64,
            m.machine.os,
            m.software.rustc
        );
    }
    let _ = writeln!(s, "| file | content |\n|---|---|");
    for spec in &PAPER_FIGURES {
        let _ = writeln!(s, "| {}.png / .svg | {} |", spec.stem(), spec.title());
    }
    let _ = writeln!(s, "| fig_memory.png / .svg | Peak memory vs threads, AE vs DD, per model (claims C2, C6) |\n");
    let _ = writeln!(
        s,
        "Each of Figures 7-14 has three panels: (a) total computation (steady-state time per step), \
         (b) grid-node stage, (c) particle stage (stage seconds per step). Speedup = T1/Tn, efficiency = \
         speedup/n (paper Eqs. 19-20), ratios of medians over repetitions; bars are 95 % percentile-bootstrap \
         intervals (2000 resamples, fixed seed), absent with a single repetition. Hollow markers joined by \
         dotted lines are oversubscribed runs (more threads than usable cores: time sharing, not scaling). \
         Configurations without an `ok` run are absent, not zero."
    );
    let unmeasured = an.unmeasured();
    if !unmeasured.is_empty() {
        let _ = writeln!(s, "\nConfigurations without a measurement:\n");
        for (k, cell) in unmeasured {
            let why = cell.not_ok.first().map(|(st, r)| format!("{}: {r}", st.as_str())).unwrap_or_default();
            let _ = writeln!(s, "- {k}: {why}");
        }
    }
    for n in &an.notes {
        let _ = writeln!(s, "\nNote: {n}");
    }
    s
}

/// `mpm-bench figures`.
pub fn run(args: FiguresArgs) -> Result<()> {
    let c = load_campaign(&args.results)?;
    let an = c.analyse(args.pin.as_deref());
    if an.points.is_empty() {
        eprintln!("warning: campaign {} has no ok run: the figures will be empty", c.dir.display());
    }
    let mut command = format!("mpm-bench figures --results {} --out {}", args.results.display(), args.out.display());
    if let Some(p) = &args.pin {
        let _ = write!(command, " --pin {p}");
    }
    let files = write_all(&c, &an, &args.out, &command)?;
    println!("campaign {} ({}): wrote {} files to {}", c.id(), c.dir.display(), files.len(), args.out.display());
    for f in files {
        println!("  {}", f.display());
    }
    Ok(())
}
