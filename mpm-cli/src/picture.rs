//! Pictures: the radiograph-style side view of the debris cloud (paper Section 6) and the
//! cloud's history (front and width against time).
//!
//! Text is rendered with the font compiled into the program ([`mpm_host::fonts`]): no figure
//! depends on the fonts a machine has installed.

use mpm_core::scenario::impact::{radiograph, HistorySample};
use mpm_core::Particles;
use mpm_host::fonts::register_fonts;
use plotters::backend::DrawingBackend;
use plotters::drawing::DrawingAreaErrorKind;
use plotters::prelude::*;
use std::path::{Path, PathBuf};

/// What plotters says when a figure cannot be drawn or saved.
pub type DrawError = DrawingAreaErrorKind<<BitMapBackend<'static> as DrawingBackend>::ErrorType>;

/// Why a picture was not written.
#[derive(Debug, thiserror::Error)]
pub enum PictureError {
    /// Drawing failed.
    #[error(transparent)]
    Draw(#[from] DrawError),
    /// The radiograph's pixels do not fill the plotting area.
    #[error("radiograph buffer does not match the plotting area")]
    Buffer,
    /// The PNG file cannot be written.
    #[error("cannot write the {what} {path}")]
    Write {
        /// `radiograph` or `history plot`.
        what: &'static str,
        /// The file.
        path: PathBuf,
        /// What plotters said.
        source: DrawError,
    },
}

/// The error of a PNG file `path` (a `what`) that cannot be written.
fn unwritten(what: &'static str, path: &Path) -> impl FnOnce(DrawError) -> PictureError {
    let path = path.to_path_buf();
    move |source| PictureError::Write { what, path, source }
}

/// What to annotate on a radiograph.
#[derive(Clone, Debug)]
pub struct RadiographNotes {
    /// Time after impact (s).
    pub time: f64,
    /// z of the plate's front and rear faces before impact (m), drawn as dashed lines.
    pub plate_faces: (f64, f64),
    /// Text lines printed in the corner (measured figures).
    pub lines: Vec<String>,
}

/// Render the particles' mass projected along y onto the x-z plane (the plane containing
/// the flight axis, z up) as a PNG of `width x height` pixels, dense material dark on white
/// like a flash radiograph print; each particle covers a square of its lattice `spacing`.
/// The frame covers every particle with a small margin.
pub fn write_radiograph(
    path: &Path,
    particles: &Particles,
    spacing: f64,
    notes: &RadiographNotes,
    size: (u32, u32),
) -> Result<(), PictureError> {
    register_fonts();
    let (lo, hi) = particles.bounding_box();
    let clamp = |v: f64| v.clamp(-0.5, 0.5);
    let half_x = clamp(lo[0].abs().max(hi[0].abs())) * 1.05 + 1e-3;
    let (z0, z1) = (clamp(lo[2]), clamp(hi[2]));
    let pad = 0.04 * (z1 - z0) + 1e-3;
    let (z0, z1) = (z0 - pad, z1 + pad);
    let (xr, zr) = ((-half_x * 1e3)..(half_x * 1e3), (z0 * 1e3)..(z1 * 1e3));

    let root = BitMapBackend::new(path, size).into_drawing_area();
    root.fill(&WHITE)?;
    let title = format!("Debris cloud {:.1} µs after impact (mass projected along y)", notes.time * 1e6);
    let mut chart = ChartBuilder::on(&root)
        .caption(title, ("sans-serif", 20))
        .margin(12)
        .x_label_area_size(40)
        .y_label_area_size(55)
        .build_cartesian_2d(xr.clone(), zr.clone())?;
    chart
        .configure_mesh()
        .disable_mesh()
        .x_desc("x (mm)")
        .y_desc("z (mm), flight direction up")
        .label_style(("sans-serif", 14))
        .draw()?;

    let (w, h) = chart.plotting_area().dim_in_pixel();
    let img = radiograph(particles, (-half_x, half_x), (z0, z1), w as usize, h as usize, spacing);
    let max = img.iter().copied().fold(0.0f64, f64::max).max(f64::MIN_POSITIVE);
    // Logarithmic contrast: thin spray stays visible next to the dense core.
    let scale = |d: f64| ((1.0 + 200.0 * d / max).ln() / (201.0f64).ln()).clamp(0.0, 1.0);
    let mut buf = vec![255u8; (w * h * 3) as usize];
    for row in 0..h as usize {
        let k = h as usize - 1 - row; // image row 0 is the top (largest z)
        for i in 0..w as usize {
            let g = (255.0 * (1.0 - scale(img[k * w as usize + i]))).round() as u8;
            let o = 3 * (row * w as usize + i);
            buf[o..o + 3].copy_from_slice(&[g, g, g]);
        }
    }
    let bitmap = BitMapElement::with_owned_buffer((xr.start, zr.end), (w, h), buf).ok_or(PictureError::Buffer)?;
    chart.draw_series(std::iter::once(bitmap))?;

    let dashed = RED.mix(0.6).stroke_width(1);
    for z in [notes.plate_faces.0, notes.plate_faces.1] {
        chart.draw_series(DashedLineSeries::new(vec![(xr.start, z * 1e3), (xr.end, z * 1e3)], 6, 4, dashed))?;
    }
    let mut y = 10;
    for line in &notes.lines {
        chart.plotting_area().draw(&Text::new(
            line.clone(),
            (xr.start + 0.02 * (xr.end - xr.start), zr.end - (y as f64) * (zr.end - zr.start) / h as f64),
            ("sans-serif", 14).into_font().color(&BLUE),
        ))?;
        y += 18;
    }
    root.present().map_err(unwritten("radiograph", path))
}

/// Draw the debris cloud's leading edge and width against time (µs) as a PNG of `size`
/// pixels: extreme values as dashed lines, robust ones (ignoring the outermost 0.1 % of the
/// debris mass) as solid lines with markers at the samples.
pub fn write_history_plot(path: &Path, samples: &[HistorySample], size: (u32, u32)) -> Result<(), PictureError> {
    register_fonts();
    let t_end = samples.iter().map(|s| s.time * 1e6).fold(0.0f64, f64::max).max(1e-3);
    let top = samples.iter().map(|s| s.cloud_front.max(s.cloud_width) * 1e3).fold(0.0f64, f64::max);
    let top = if top > 0.0 { 1.08 * top } else { 1.0 };
    let root = BitMapBackend::new(path, size).into_drawing_area();
    root.fill(&WHITE)?;
    let mut chart = ChartBuilder::on(&root)
        .caption("Debris cloud behind the plate", ("sans-serif", 20))
        .margin(12)
        .x_label_area_size(40)
        .y_label_area_size(55)
        .build_cartesian_2d(0.0..t_end * 1.02, 0.0..top)?;
    chart
        .configure_mesh()
        .x_desc("time after impact (µs)")
        .y_desc("distance (mm)")
        .label_style(("sans-serif", 14))
        .draw()?;
    type Pick = fn(&HistorySample) -> f64;
    let series: [(&str, Pick, RGBColor, bool); 4] = [
        ("leading edge, extreme", |s| s.cloud_front, BLUE, false),
        ("leading edge, robust", |s| s.cloud_front_robust, BLUE, true),
        ("width, extreme", |s| s.cloud_width, RED, false),
        ("width, robust", |s| s.cloud_width_robust, RED, true),
    ];
    for (label, pick, colour, robust) in series {
        let pts: Vec<(f64, f64)> = samples.iter().map(|s| (s.time * 1e6, pick(s) * 1e3)).collect();
        let style = colour.stroke_width(if robust { 2 } else { 1 });
        if robust {
            chart
                .draw_series(LineSeries::new(pts.clone(), style))?
                .label(label)
                .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], style));
            chart.draw_series(pts.iter().map(|&p| Circle::new(p, 3, colour.filled())))?;
        } else {
            chart.draw_series(DashedLineSeries::new(pts, 6, 4, style))?.label(label).legend(move |at| {
                EmptyElement::at(at)
                    + PathElement::new(vec![(0, 0), (7, 0)], style)
                    + PathElement::new(vec![(13, 0), (20, 0)], style)
            });
        }
    }
    chart
        .configure_series_labels()
        .position(SeriesLabelPosition::UpperLeft)
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK)
        .label_font(("sans-serif", 14))
        .draw()?;
    root.present().map_err(unwritten("history plot", path))
}

#[cfg(test)]
mod tests {
    use super::*;
    use mpm_core::scenario::impact::Impact;

    #[test]
    fn radiograph_png_is_written() {
        let (setup, g) = Impact { spacing: 2.0e-3, ..Default::default() }.setup().unwrap();
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("r.png");
        let notes = RadiographNotes { time: 0.0, plate_faces: (0.0, g.rear_face), lines: vec!["test".into()] };
        write_radiograph(&path, &setup.particles, 2.0e-3, &notes, (640, 480)).unwrap();
        let bytes = std::fs::read(&path).unwrap();
        assert_eq!(&bytes[1..4], b"PNG");
        assert!(bytes.len() > 2000);
    }

    #[test]
    fn history_png_is_written() {
        let sample = |t: f64| HistorySample {
            time: t * 1e-6,
            cloud_front: 6.0e-3 * t,
            cloud_front_robust: 5.8e-3 * t,
            cloud_width: 3.0e-3 * t,
            cloud_width_robust: 2.5e-3 * t,
            kinetic: 1.0,
            internal: 0.0,
            total: 1.0,
            failed: 0,
        };
        let samples: Vec<HistorySample> = (0..=30).map(|t| sample(t as f64)).collect();
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("h.png");
        write_history_plot(&path, &samples, (800, 500)).unwrap();
        let bytes = std::fs::read(&path).unwrap();
        assert_eq!(&bytes[1..4], b"PNG");
        assert!(bytes.len() > 2000);
        // No samples still gives a (blank) figure rather than an error.
        write_history_plot(&path, &[], (400, 300)).unwrap();
    }
}
