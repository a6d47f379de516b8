//! Drawing: panels of lines with interval bars, hollow (oversubscribed) and grey (busy host)
//! markers, a legend
//! strip, footnotes, and a figure written as PNG and SVG with the embedded font
//! ([`mpm_host::fonts::register_fonts`]).

use anyhow::{anyhow, Context, Result};
use mpm_host::fonts::register_fonts;
use plotters::coord::Shift;
use plotters::prelude::*;
use std::path::{Path, PathBuf};

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
    /// Drawn grey (measured on a busy host, `host_noisy`).
    pub grey: bool,
    /// Crossed out in red: flagged (e.g. a speedup above the cores the run had), not plain
    /// data.
    pub flagged: bool,
}

/// Colour of the cross over a flagged point.
pub const FLAG_RED: RGBColor = RGBColor(220, 0, 0);

/// Colour of the markers of points measured on a busy host.
pub const NOISY_GREY: RGBColor = RGBColor(150, 150, 150);

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

impl Panel {
    /// A panel titled `title` with the number of threads on x (up to `x_max`) and `y_desc`
    /// on y (up to `y_max`), without an ideal line.
    pub fn of_threads(
        title: String,
        y_desc: String,
        x_max: f64,
        y_max: f64,
        lines: Vec<Line>,
        notes: Vec<String>,
    ) -> Self {
        let x_desc = "Number of threads".to_string();
        Self { title, y_desc, x_desc, x_max, y_max, ideal: None, ideal_flat: false, lines, notes }
    }
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
    let colour = if p.grey { NOISY_GREY } else { line.colour };
    let layers: Vec<(i32, ShapeStyle)> =
        if p.hollow { vec![(7, colour.filled()), (4, WHITE.filled())] } else { vec![(6, colour.filled())] };
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
    if p.flagged {
        let style = ShapeStyle { color: FLAG_RED.to_rgba(), filled: false, stroke_width: 3 };
        for (d0, d1) in [((-9, -9), (9, 9)), ((-9, 9), (9, -9))] {
            chart
                .draw_series(std::iter::once(EmptyElement::at(at) + PathElement::new(vec![d0, d1], style)))
                .map_err(pe)?;
        }
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
    // (Up to 5 the ticks are 0.5 apart: one decimal, or 1.5 would read as 2.)
    let decimals = if panel.y_max > 5.0 {
        0
    } else if panel.y_max > 2.0 {
        1
    } else {
        (-(panel.y_max / 10.0).log10()).ceil().max(1.0) as usize
    };
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
        draw_line(&mut chart, line)?;
    }
    draw_notes(area, &panel.notes)?;
    Ok(())
}

/// One line of a panel: its segments (solid between real points, dotted when either end is
/// hollow, dashed for a dashed line), error bars and markers.
fn draw_line<DB: DrawingBackend>(
    chart: &mut ChartContext<
        '_,
        DB,
        Cartesian2d<plotters::coord::types::RangedCoordf64, plotters::coord::types::RangedCoordf64>,
    >,
    line: &Line,
) -> Result<()> {
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
                .draw_series(std::iter::once(ErrorBar::new_vertical(p.x, p.lo, p.y, p.hi, colour.stroke_width(1), 8)))
                .map_err(pe)?;
        }
        draw_marker(chart, p, line)?;
    }
    Ok(())
}

/// The panel's notes, right-aligned at its bottom.
fn draw_notes<DB: DrawingBackend>(area: &DrawingArea<DB, Shift>, notes: &[String]) -> Result<()> {
    if !notes.is_empty() {
        let (w, h) = area.dim_in_pixel();
        let k = notes.len() as i32;
        for (i, n) in notes.iter().enumerate() {
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
    if panels.iter().any(|p| p.lines.iter().any(|l| l.points.iter().any(|q| q.grey))) {
        items.push(("grey marker: measured on a busy host (host_noisy)".into(), None, false));
    }
    if panels.iter().any(|p| p.lines.iter().any(|l| l.points.iter().any(|q| q.flagged))) {
        items.push(("red cross: flagged, not data (speedup above the cores; see points.csv)".into(), None, false));
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

/// Draw a figure (title, panels in a grid, footnotes) as an SVG document in memory, for
/// pages that inline their figures.
pub fn svg_string(
    size: (u32, u32),
    title: &str,
    panels: &[Panel],
    grid: (usize, usize),
    footnotes: &[String],
) -> Result<String> {
    register_fonts();
    let mut svg = String::new();
    {
        let root = SVGBackend::with_string(&mut svg, size).into_drawing_area();
        draw_figure(&root, title, panels, grid, footnotes)?;
        root.present().map_err(pe)?;
    }
    Ok(svg)
}
