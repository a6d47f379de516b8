//! Problem set-ups: the Taylor bar Models 1-4 ([`taylor`]), the hypervelocity impact
//! ([`impact`]), the 1D plate-impact validation ([`plate`]) and lattice seeding helpers
//! ([`lattice`]). A scenario produces a [`Setup`]; [`crate::Simulation::new`] takes it.

pub mod impact;
pub mod lattice;
pub mod plate;
pub mod size;
pub mod taylor;

use crate::grid::{GridSpec, Wall};
use crate::material::Material;
use crate::math::Vec3;
use crate::particles::Particles;

/// Everything a simulation needs from a scenario.
#[derive(Clone, Debug)]
pub struct Setup {
    /// Scenario name (`taylor`, `impact`, or a test's own).
    pub scenario: String,
    /// Model label (`Model1` ... `Model4`).
    pub model: String,
    /// Particles in their initial state.
    pub particles: Particles,
    /// The material of every particle.
    pub material: Material,
    /// The grid (fixed extent; the adaptive grid keeps its cell size and lattice).
    pub grid: GridSpec,
    /// Rigid walls.
    pub walls: Vec<Wall>,
    /// Particle lattice spacing per axis (m), used by the measurements.
    pub spacing: Vec3,
}

/// The least-squares line `y = slope x + intercept` through `points`: `(slope, intercept)`,
/// `None` with fewer than two points or no spread in `x`.
pub fn fit_line(points: &[(f64, f64)]) -> Option<(f64, f64)> {
    if points.len() < 2 {
        return None;
    }
    let n = points.len() as f64;
    let mx = points.iter().map(|p| p.0).sum::<f64>() / n;
    let my = points.iter().map(|p| p.1).sum::<f64>() / n;
    let (mut sxy, mut sxx) = (0.0, 0.0);
    for &(x, y) in points {
        sxy += (x - mx) * (y - my);
        sxx += (x - mx) * (x - mx);
    }
    if sxx <= 0.0 {
        return None;
    }
    let slope = sxy / sxx;
    Some((slope, my - slope * mx))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fit_line_recovers_a_line_and_refuses_degenerate_input() {
        let pts: Vec<(f64, f64)> = (0..5).map(|i| (i as f64, 3.0 * i as f64 - 2.0)).collect();
        let (a, b) = fit_line(&pts).unwrap();
        assert!((a - 3.0).abs() < 1e-12 && (b + 2.0).abs() < 1e-12);
        // Symmetric noise around the line does not change the slope.
        let noisy = [(0.0, 0.1), (1.0, 0.9), (2.0, 2.1), (3.0, 2.9)];
        assert!((fit_line(&noisy).unwrap().0 - 0.96).abs() < 1e-12);
        assert_eq!(fit_line(&[(1.0, 2.0)]), None);
        assert_eq!(fit_line(&[(1.0, 2.0), (1.0, 3.0)]), None);
    }
}
