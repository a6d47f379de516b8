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

/// Which of a scenario's particles a set-up builds.
#[derive(Clone, Copy, Default)]
pub enum Pick<'a> {
    /// Every particle (one process).
    #[default]
    All,
    /// Only the particles whose initial position the filter accepts (one rank's box),
    /// generated one at a time and filtered, so the whole set is never held; the set-up's
    /// [`Setup::part`] tells which they are.
    Where(&'a dyn Fn(Vec3) -> bool),
}

/// What a set-up built for [`Pick::Where`] knows of the whole set its particles come from.
#[derive(Clone, Debug, PartialEq)]
pub struct Part {
    /// Index in the whole set of each particle kept, increasing.
    pub ids: Vec<u64>,
    /// Particles in the whole set.
    pub total: u64,
    /// Smallest coordinate of any particle of the whole set, per axis.
    pub lo: Vec3,
    /// Largest coordinate of any particle of the whole set, per axis.
    pub hi: Vec3,
}

/// The particles `generate` describes, as `pick` asks.
///
/// `generate` calls its argument with the position and velocity of every particle of the
/// whole set (`count` of them), in the set's order, and does the same on every call; all
/// particles have the same `mass`, density `rho` and `sound` speed. [`Pick::All`] calls it
/// once; [`Pick::Where`] twice (count the particles kept, then build exactly that many), so
/// the arrays hold only the kept particles.
pub(crate) fn seed(
    pick: Pick<'_>,
    count: usize,
    [mass, rho, sound]: [f64; 3],
    generate: impl Fn(&mut dyn FnMut(Vec3, Vec3)),
) -> (Particles, Option<Part>) {
    let Pick::Where(keep) = pick else {
        let mut particles = Particles::with_capacity(count);
        generate(&mut |x, v| particles.push(x, v, mass, rho, sound));
        return (particles, None);
    };
    let (mut kept, mut total, mut lo, mut hi) = (0, 0u64, [f64::INFINITY; 3], [f64::NEG_INFINITY; 3]);
    generate(&mut |x, _| {
        kept += usize::from(keep(x));
        total += 1;
        for d in 0..3 {
            lo[d] = lo[d].min(x[d]);
            hi[d] = hi[d].max(x[d]);
        }
    });
    let mut particles = Particles::with_capacity(kept);
    let mut ids = Vec::with_capacity(kept);
    let mut index = 0u64;
    generate(&mut |x, v| {
        if keep(x) {
            particles.push(x, v, mass, rho, sound);
            ids.push(index);
        }
        index += 1;
    });
    (particles, Some(Part { ids, total, lo, hi }))
}

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
    /// `None`: `particles` is the whole set; otherwise the part of it one rank built
    /// ([`Pick::Where`]).
    pub part: Option<Part>,
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

    /// Five particles on a line; the filter keeps those with x > 1.5.
    fn five(pick: Pick<'_>) -> (Particles, Option<Part>) {
        seed(pick, 5, [2.0, 3.0, 4.0], |f| (0..5).for_each(|i| f([i as f64, -(i as f64), 0.5], [i as f64; 3])))
    }

    #[test]
    fn a_picked_seed_keeps_the_filtered_particles_with_their_indices_and_the_whole_box() {
        let (all, none) = five(Pick::All);
        assert!(none.is_none());
        assert_eq!((all.len(), all.x.capacity()), (5, 5));
        let keep = |x: Vec3| x[0] > 1.5;
        let (some, part) = five(Pick::Where(&keep));
        let part = part.unwrap();
        assert_eq!(part, Part { ids: vec![2, 3, 4], total: 5, lo: [0.0, -4.0, 0.5], hi: [4.0, 0.0, 0.5] });
        assert_eq!((some.len(), some.x.capacity()), (3, 3));
        for (k, &id) in part.ids.iter().enumerate() {
            let i = id as usize;
            assert_eq!((some.x[k], some.v[k], some.mass[k]), (all.x[i], all.v[i], all.mass[i]));
        }
    }

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
