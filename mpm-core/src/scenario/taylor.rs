//! The Taylor bar benchmark (paper Section 3): an OFHC copper cylinder, `L0 = 25.4 mm`
//! long and `D0 = 7.6 mm` across, axis along z, hitting a rigid wall at `z = 0` (the bar
//! touches the wall at `t = 0`).
//!
//! Models 1-4 reproduce Table 2: cubic cells `dx = L0 / nz` (nz = 48, 72, 132, 264), the grid
//! spans `z` in `[0, L0]` and `2/3 L0` laterally, centred on the axis; particles sit at the
//! cell centres of a lattice over the bar's bounding box (`n_d` points across the diameter,
//! `n_l` layers along the length), kept when `x^2 + y^2 <= R^2`.
//!
//! | model | lattice | particles | cells | nodes |
//! |---|---|---|---|---|
//! | 1 | 28 x 91 | 616 x 91 = 56,056 | 32 x 32 x 48 = 49,152 | 53,361 |
//! | 2 | 45 x 153 | 1,597 x 153 = 244,341 (Table 2: 244,524, -0.07 %) | 48 x 48 x 72 = 165,888 | 175,273 |
//! | 3 | 76 x 254 | 4,548 x 254 = 1,155,192 | 88 x 88 x 132 = 1,022,208 | 1,053,493 |
//! | 4 | 168 x 560 | 22,172 x 560 = 12,416,320 | 176 x 176 x 264 = 8,177,664 | 8,302,185 |
//!
//! Particle mass is `density x bar volume / particle count`, so the bar has its true mass
//! (`pi R^2 L0 rho = 10.28 g`) at every resolution.
//!
//! Particle numbering: octant by octant of the grid (x halves first, then y, then z; layer by
//! layer within an octant). With the domain decomposition's z-fastest patch numbering, the
//! contiguous particle chunk of worker j (loop splitting) and patch j (scatter) then cover the
//! same region for the paper's 2, 4 and 8-thread layouts, so each worker's data stays in its
//! own core's caches instead of moving between cores every step (with a numbering that
//! mixes the regions, DD on Model 3 at 2 threads reaches 0.76 efficiency instead of 0.90).
//! The numbering changes only the order of floating-point sums, not the physics.
//!
//! Measurements ([`measure`]): the length is `max z - min z` of the particle centres plus one
//! layer spacing (half a spacing beyond the end particles at each end), so it is exactly `L0`
//! at `t = 0`. The impact-face diameter is taken from particle centres: twice the largest
//! radial distance in the bottom layer band; the lattice's outermost points lie on the
//! circle's diagonals within a few microns of `R`, so at `t = 0` it is within 0.5 % of `D0`.
//! Both are extremes, so a run split over ranks measures them with two maxima over the ranks
//! ([`measure_over`]), exactly.

use super::{lattice, seed, Pick, Setup};
use crate::error::SimError;
use crate::exchange::{Collectives, SingleProcess};
use crate::grid::{GridSpec, Wall, WallKind};
use crate::material::{Material, MgForm};
use crate::math::Vec3;
use crate::particles::Particles;
use serde::{Deserialize, Serialize};

/// Bar length `L0` (m).
pub const LENGTH: f64 = 25.4e-3;
/// Bar diameter `D0` (m).
pub const DIAMETER: f64 = 7.6e-3;
/// Default impact speed (m/s).
pub const DEFAULT_VELOCITY: f64 = 40.0;
/// Default end time (s).
pub const DEFAULT_END_TIME: f64 = 40e-6;

/// The numbers that define one of Models 1-4.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
pub struct ModelSpec {
    /// Model number (1-4).
    pub model: u8,
    /// Cells along z (`dx = L0 / nz`).
    pub nz: usize,
    /// Cells along x and y.
    pub nxy: usize,
    /// Lattice points across the diameter.
    pub n_diameter: usize,
    /// Lattice layers along the length.
    pub n_layers: usize,
    /// Particles of Table 2 (the paper's figure; Model 2 differs from ours by 183).
    pub table2_particles: usize,
}

impl ModelSpec {
    /// Models 1-4 of Table 2.
    pub const ALL: [ModelSpec; 4] = [
        ModelSpec { model: 1, nz: 48, nxy: 32, n_diameter: 28, n_layers: 91, table2_particles: 56_056 },
        ModelSpec { model: 2, nz: 72, nxy: 48, n_diameter: 45, n_layers: 153, table2_particles: 244_524 },
        ModelSpec { model: 3, nz: 132, nxy: 88, n_diameter: 76, n_layers: 254, table2_particles: 1_155_192 },
        ModelSpec { model: 4, nz: 264, nxy: 176, n_diameter: 168, n_layers: 560, table2_particles: 12_416_320 },
    ];

    /// Model `m` (1-4).
    pub fn get(m: u8) -> Result<ModelSpec, SimError> {
        Self::ALL.iter().find(|s| s.model == m).copied().ok_or_else(|| {
            SimError::Config(format!("unknown Taylor bar model {m}: the paper defines models 1, 2, 3 and 4"))
        })
    }

    /// Cell size (m).
    pub fn dx(&self) -> f64 {
        LENGTH / self.nz as f64
    }

    /// Cells of the fixed grid.
    pub fn cells(&self) -> usize {
        self.nxy * self.nxy * self.nz
    }

    /// Nodes of the fixed grid.
    pub fn nodes(&self) -> usize {
        (self.nxy + 1) * (self.nxy + 1) * (self.nz + 1)
    }

    /// Lattice spacing `[h, h, h_z]` (m).
    pub fn spacing(&self) -> Vec3 {
        let h = DIAMETER / self.n_diameter as f64;
        [h, h, LENGTH / self.n_layers as f64]
    }

    /// Particles per layer (lattice points inside the circle).
    pub fn per_layer(&self) -> usize {
        self.layer_points().len()
    }

    /// Particles in the bar.
    pub fn particles(&self) -> usize {
        self.per_layer() * self.n_layers
    }

    fn layer_points(&self) -> Vec<Vec3> {
        let r = 0.5 * DIAMETER;
        let h = self.spacing();
        lattice::cell_centred([-r, -r, 0.0], [h[0], h[1], 1.0], [self.n_diameter, self.n_diameter, 1], |p| {
            p[0] * p[0] + p[1] * p[1] <= r * r
        })
    }
}

/// A Taylor bar impact.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct TaylorBar {
    /// Model 1-4.
    pub model: u8,
    /// Impact speed towards the wall (m/s, positive).
    pub velocity: f64,
    /// Mie-Grüneisen form.
    pub eos: MgForm,
    /// Wall condition.
    pub wall: WallKind,
}

impl Default for TaylorBar {
    fn default() -> Self {
        Self { model: 1, velocity: DEFAULT_VELOCITY, eos: MgForm::default(), wall: WallKind::Slip }
    }
}

impl TaylorBar {
    /// Build the particles, grid and wall.
    pub fn setup(&self) -> Result<Setup, SimError> {
        self.setup_picked(Pick::All)
    }

    /// Build the grid, the wall and the particles `pick` asks for.
    pub fn setup_picked(&self, pick: Pick<'_>) -> Result<Setup, SimError> {
        let spec = ModelSpec::get(self.model)?;
        if !(self.velocity.is_finite() && self.velocity >= 0.0) {
            return Err(SimError::Config(format!(
                "impact velocity must be a finite speed >= 0 m/s, got {}",
                self.velocity
            )));
        }
        let material = Material::ofhc_copper(self.eos);
        let h = spec.spacing();
        let layer = spec.layer_points();
        let count = layer.len() * spec.n_layers;
        let volume = std::f64::consts::PI * 0.25 * DIAMETER * DIAMETER * LENGTH;
        let mass = material.density * volume / count as f64;
        let c = material.reference_sound_speed();
        let v = [0.0, 0.0, -self.velocity];
        let (particles, part) = seed(pick, count, [mass, material.density, c], |f| {
            for_each_position(&spec, &layer, &mut |x| f(x, v));
        });
        let dx = spec.dx();
        let half = 0.5 * spec.nxy as f64 * dx;
        Ok(Setup {
            scenario: "taylor".into(),
            model: format!("Model{}", spec.model),
            particles,
            material,
            grid: GridSpec { dx, anchor: [-half, -half, 0.0], cells: [spec.nxy, spec.nxy, spec.nz] },
            walls: vec![Wall { axis: 2, position: 0.0, kind: self.wall }],
            spacing: h,
            part,
        })
    }
}

/// Call `f` with the position of every particle of the bar, in the set's order: octant by
/// octant of the grid (x halves first, then y, then z; layer by layer within an octant), so
/// that the contiguous particle chunks of 2, 4 and 8 threads cover the same regions as the
/// domain-decomposition patches of the paper's layouts and each worker's data stays in its
/// own core's caches. `layer` is [`ModelSpec::layer_points`].
fn for_each_position(spec: &ModelSpec, layer: &[Vec3], f: &mut dyn FnMut(Vec3)) {
    let hz = spec.spacing()[2];
    for octant in 0..8u8 {
        let (upper_x, upper_y, upper_z) = (octant & 4 != 0, octant & 2 != 0, octant & 1 != 0);
        for k in 0..spec.n_layers {
            let z = (k as f64 + 0.5) * hz;
            if (z >= 0.5 * LENGTH) != upper_z {
                continue;
            }
            for p in layer.iter().filter(|p| (p[0] >= 0.0) == upper_x && (p[1] >= 0.0) == upper_y) {
                f([p[0], p[1], z]);
            }
        }
    }
}

/// Shape figures of a deformed bar.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct TaylorFigures {
    /// `max z - min z` of the particle centres plus one layer spacing (m).
    pub length: f64,
    /// Impact-face diameter: twice the largest radial distance of the particle centres in the
    /// bottom layer band (`z <= min z + h_z / 2`) (m).
    pub face_diameter: f64,
}

/// Measure the bar of one process's particles (see the module docs for the conventions).
pub fn measure(particles: &Particles, spacing: Vec3) -> TaylorFigures {
    measure_over(particles, spacing, &mut SingleProcess).expect("one process's collectives cannot fail")
}

/// Measure the bar whose particles are spread over ranks, `particles` being this rank's:
/// collective (every rank calls it, [`Collectives`]), and every rank gets the figures of
/// the whole set. They are extremes only (maxima over ranks are exact), so they are
/// bitwise those of one process holding every particle.
pub fn measure_over(
    particles: &Particles,
    spacing: Vec3,
    ranks: &mut dyn Collectives,
) -> Result<TaylorFigures, SimError> {
    // -min z and max z.
    let mut ends = [f64::NEG_INFINITY; 2];
    for x in &particles.x {
        ends = [ends[0].max(-x[2]), ends[1].max(x[2])];
    }
    ranks.max(&mut ends)?;
    let (lo, hi) = (-ends[0], ends[1]);
    let band = lo + 0.5 * spacing[2];
    let mut r2 = [0.0f64];
    for x in particles.x.iter().filter(|x| x[2] <= band) {
        r2[0] = r2[0].max(x[0] * x[0] + x[1] * x[1]);
    }
    ranks.max(&mut r2)?;
    Ok(TaylorFigures { length: hi - lo + spacing[2], face_diameter: 2.0 * r2[0].sqrt() })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::grid::GridGeom;

    #[test]
    fn table2_counts() {
        let expect = [
            (56_056, 49_152, 53_361),
            (244_341, 165_888, 175_273),
            (1_155_192, 1_022_208, 1_053_493),
            (12_416_320, 8_177_664, 8_302_185),
        ];
        for (spec, (p, c, n)) in ModelSpec::ALL.iter().zip(expect) {
            assert_eq!(spec.particles(), p, "model {}", spec.model);
            assert_eq!(spec.cells(), c);
            assert_eq!(spec.nodes(), n);
        }
    }

    #[test]
    fn model1_setup_matches_the_spec_and_fits_the_grid() {
        let s = TaylorBar::default().setup().unwrap();
        assert_eq!(s.particles.len(), 56_056);
        let g = GridGeom::fixed(&s.grid);
        assert_eq!(g.num_cells(), 49_152);
        assert_eq!(g.num_nodes(), 53_361);
        assert!(s.particles.x.iter().all(|&x| g.contains(x)));
        let mass = s.particles.total_mass();
        let expect = 8930.0 * std::f64::consts::PI * 0.25 * DIAMETER * DIAMETER * LENGTH;
        assert!((mass / expect - 1.0).abs() < 1e-12);
        let f = measure(&s.particles, s.spacing);
        assert!((f.length - LENGTH).abs() < 1e-12);
        assert!((f.face_diameter - DIAMETER).abs() < 0.005 * DIAMETER, "{}", f.face_diameter);
    }

    /// The particle numbering is the one the set-up has always had: the lattice layer by
    /// layer, stably sorted by octant.
    #[test]
    fn particles_are_numbered_octant_by_octant_and_a_pick_keeps_that_numbering() {
        let bar = TaylorBar::default();
        let s = bar.setup().unwrap();
        let spec = ModelSpec::get(1).unwrap();
        let mut sorted: Vec<(u8, Vec3)> = Vec::new();
        for k in 0..spec.n_layers {
            let z = (k as f64 + 0.5) * spec.spacing()[2];
            for p in spec.layer_points() {
                sorted.push((
                    4 * u8::from(p[0] >= 0.0) + 2 * u8::from(p[1] >= 0.0) + u8::from(z >= 0.5 * LENGTH),
                    [p[0], p[1], z],
                ));
            }
        }
        sorted.sort_by_key(|p| p.0);
        assert!(s.particles.x.iter().zip(&sorted).all(|(a, b)| *a == b.1));
        let keep = |x: Vec3| x[2] < 0.3 * LENGTH && x[0] > 0.0;
        let picked = bar.setup_picked(Pick::Where(&keep)).unwrap();
        let part = picked.part.unwrap();
        assert_eq!(part.total, 56_056);
        assert_eq!((part.lo, part.hi), s.particles.bounding_box());
        let expect: Vec<u64> = (0..s.particles.len() as u64).filter(|&p| keep(s.particles.x[p as usize])).collect();
        assert_eq!(part.ids, expect);
        assert!(part.ids.iter().enumerate().all(|(k, &p)| picked.particles.x[k] == s.particles.x[p as usize]));
        assert_eq!(picked.particles.mass[0], s.particles.mass[0]);
    }

    #[test]
    fn unknown_model_is_a_clear_error() {
        let e = TaylorBar { model: 5, ..Default::default() }.setup().unwrap_err();
        assert!(e.to_string().contains("models 1, 2, 3 and 4"));
    }
}
