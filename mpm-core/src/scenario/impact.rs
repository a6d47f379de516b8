//! The hypervelocity impact of paper Section 6: a lead sphere (radius 7.5 mm, 20 g) at
//! 6.58 km/s, normal incidence, on a lead plate 6.35 mm thick and 140 mm x 140 mm (Table 3
//! with failure), compared at 30.6 µs after impact with a flash radiograph of the debris
//! cloud.
//!
//! Geometry: the flight direction is `+z`. The plate fills `[-70, 70] mm^2 x [0, 6.35] mm`,
//! so its front face is `z = 0` and its rear face `z = 6.35 mm`; the sphere's centre starts
//! on the axis at `z = -(R + h/2)` so the bodies touch at `t = 0` (impact time 0).
//!
//! Particles: both bodies are seeded on cell-centred lattices of spacing `h` (default
//! 0.53 mm): the plate with `round(140 mm / h)^2 x round(6.35 mm / h)` points (spacings
//! adjusted per axis so its dimensions are exact), the sphere with the points of a lattice of
//! spacing `h` centred on it that lie inside `R`. Default: 264 x 264 x 12 = 836,352 plate +
//! 11,752 sphere = 848,104 particles (paper: 847,888, +0.03 %); at 0.21 mm, 667 x 667 x 30 +
//! 191,256 = 13,537,926 (paper: 13,542,030, -0.03 %). Each body's particles share its true
//! mass (`rho V / count`): the sphere weighs 20.06 g.
//!
//! Grid: cubic cells of `cell` (default 2.12 mm, so 4 x 4 x 4 particles per cell; 1.06 and
//! 1.59 mm are the paper's other options) on a lattice anchored at the plate's corner
//! `(-70, -70, 0) mm`, normally adaptive (it follows the debris cloud).
//!
//! Measurements ([`measure`]), all at the current state, with "debris" = every particle
//! beyond the plate's rear face (`z > 6.35 mm`):
//! * `cloud_front`: distance of the farthest debris particle centre from the rear face;
//!   `cloud_front_robust`: the same for the position beyond which lies 0.1 % of the debris
//!   mass (a few stray particles cannot move it);
//! * `cloud_width`: largest diameter normal to the flight direction, twice the largest
//!   distance of a debris particle centre from the flight axis; `cloud_width_robust`: twice
//!   the radius containing 99.9 % of the debris mass;
//! * `hole_diameter`: twice the smallest distance from the axis of a plate particle still
//!   inside the plate's slab `0 <= z <= 6.35 mm` (the rim of the hole);
//! * `front_velocity`: mass-weighted mean z-velocity of the debris beyond the robust front.

use super::{lattice, Setup};
use crate::error::SimError;
use crate::grid::GridSpec;
use crate::material::{Material, MgForm};
use crate::math::Vec3;
use crate::particles::Particles;
use serde::Serialize;

/// Sphere radius (m).
pub const SPHERE_RADIUS: f64 = 7.5e-3;
/// Impact speed (m/s).
pub const IMPACT_VELOCITY: f64 = 6580.0;
/// Plate thickness (m).
pub const PLATE_THICKNESS: f64 = 6.35e-3;
/// Plate side (m).
pub const PLATE_SIDE: f64 = 140e-3;
/// Default particle spacing (m).
pub const DEFAULT_SPACING: f64 = 0.53e-3;
/// Default cell size (m).
pub const DEFAULT_CELL: f64 = 2.12e-3;
/// The radiograph comparison time after impact (s).
pub const DEFAULT_END_TIME: f64 = 30.6e-6;

/// A sphere-on-plate impact.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Impact {
    /// Particle lattice spacing (m).
    pub spacing: f64,
    /// Grid cell size (m).
    pub cell: f64,
    /// Impact speed (m/s).
    pub velocity: f64,
    /// Mie-Grüneisen form.
    pub eos: MgForm,
}

impl Default for Impact {
    fn default() -> Self {
        Self { spacing: DEFAULT_SPACING, cell: DEFAULT_CELL, velocity: IMPACT_VELOCITY, eos: MgForm::Paper }
    }
}

/// The parts of an impact set-up the measurements need.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct ImpactGeometry {
    /// Particles `0..plate_particles` are the plate, the rest the sphere.
    pub plate_particles: usize,
    /// z of the plate's rear face (m).
    pub rear_face: f64,
}

impl Impact {
    /// Plate lattice counts `[nx, ny, nz]`.
    pub fn plate_counts(&self) -> [usize; 3] {
        let n = (PLATE_SIDE / self.spacing).round().max(1.0) as usize;
        [n, n, (PLATE_THICKNESS / self.spacing).round().max(1.0) as usize]
    }

    /// Build the plate and sphere particles and the grid.
    pub fn setup(&self) -> Result<(Setup, ImpactGeometry), SimError> {
        for (name, v) in [("spacing", self.spacing), ("cell size", self.cell)] {
            if !(v.is_finite() && v > 0.0) {
                return Err(SimError::Config(format!("the impact {name} must be a positive length in m, got {v}")));
            }
        }
        if self.spacing < 0.05e-3 {
            return Err(SimError::Config(format!(
                "a particle spacing of {} m would need billions of particles; use 0.21e-3 m or more",
                self.spacing
            )));
        }
        if !(self.velocity.is_finite() && self.velocity >= 0.0) {
            return Err(SimError::Config(format!("impact velocity must be >= 0 m/s, got {}", self.velocity)));
        }
        let material = Material::lead(self.eos);
        let c = material.reference_sound_speed();
        let half = 0.5 * PLATE_SIDE;
        let n = self.plate_counts();
        let hp = [PLATE_SIDE / n[0] as f64, PLATE_SIDE / n[1] as f64, PLATE_THICKNESS / n[2] as f64];
        let plate = lattice::cell_centred([-half, -half, 0.0], hp, n, |_| true);
        let r = SPHERE_RADIUS;
        let h = self.spacing;
        let zc = -(r + 0.5 * h);
        // An even number of lattice cells across, so the points sit at half-spacings from the
        // centre (cell-centred, like every lattice of this crate).
        let m = ((2.0 * r / h).ceil() as usize + 2).next_multiple_of(2);
        let lo = -(m as f64) * 0.5 * h;
        let sphere = lattice::cell_centred([lo, lo, zc + lo], [h; 3], [m, m, m], |p| {
            p[0] * p[0] + p[1] * p[1] + (p[2] - zc) * (p[2] - zc) <= r * r
        });
        let mut particles = Particles::with_capacity(plate.len() + sphere.len());
        let plate_mass = material.density * PLATE_SIDE * PLATE_SIDE * PLATE_THICKNESS / plate.len() as f64;
        for x in &plate {
            particles.push(*x, [0.0; 3], plate_mass, material.density, c);
        }
        let sphere_mass = material.density * 4.0 / 3.0 * std::f64::consts::PI * r.powi(3) / sphere.len() as f64;
        for x in &sphere {
            particles.push(*x, [0.0, 0.0, self.velocity], sphere_mass, material.density, c);
        }
        let cells_xy = (PLATE_SIDE / self.cell).ceil() as usize;
        let setup = Setup {
            scenario: "impact".into(),
            model: format!("impact-h{:.2}mm-dx{:.2}mm", h * 1e3, self.cell * 1e3),
            particles,
            material,
            grid: GridSpec {
                dx: self.cell,
                anchor: [-half, -half, 0.0],
                cells: [cells_xy, cells_xy, (PLATE_THICKNESS / self.cell).ceil() as usize],
            },
            walls: vec![],
            spacing: [h; 3],
        };
        Ok((setup, ImpactGeometry { plate_particles: plate.len(), rear_face: PLATE_THICKNESS }))
    }
}

/// Debris-cloud figures (see the module docs for definitions).
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct CloudFigures {
    /// Farthest debris particle beyond the rear face (m).
    pub cloud_front: f64,
    /// Front ignoring the leading 0.1 % of the debris mass (m).
    pub cloud_front_robust: f64,
    /// Largest debris diameter normal to the flight axis (m).
    pub cloud_width: f64,
    /// Diameter containing 99.9 % of the debris mass (m).
    pub cloud_width_robust: f64,
    /// Diameter of the hole in the plate (m); `NaN` when no plate particle is left in the slab.
    pub hole_diameter: f64,
    /// Mass-weighted z-velocity of the debris beyond the robust front (m/s).
    pub front_velocity: f64,
    /// Mass of the debris (kg).
    pub debris_mass: f64,
    /// Particles in the debris.
    pub debris_particles: usize,
}

/// Where the cumulative mass, accumulated in order of decreasing `key`, first exceeds
/// `fraction` of the total: the key of that particle.
fn mass_quantile_from_top(items: &mut [(f64, f64)], fraction: f64) -> f64 {
    items.sort_by(|a, b| b.0.total_cmp(&a.0));
    let total: f64 = items.iter().map(|i| i.1).sum();
    let mut acc = 0.0;
    for &(key, m) in items.iter() {
        acc += m;
        if acc > fraction * total {
            return key;
        }
    }
    items.last().map_or(f64::NAN, |i| i.0)
}

/// Measure the debris cloud and the hole.
pub fn measure(p: &Particles, g: &ImpactGeometry) -> CloudFigures {
    let mut front = Vec::new();
    let mut radial = Vec::new();
    let (mut zmax, mut rmax, mut mass) = (f64::NEG_INFINITY, 0.0f64, 0.0);
    let mut hole_r2 = f64::INFINITY;
    for i in 0..p.len() {
        let x: Vec3 = p.x[i];
        let r2 = x[0] * x[0] + x[1] * x[1];
        if x[2] > g.rear_face {
            front.push((x[2], p.mass[i]));
            radial.push((r2.sqrt(), p.mass[i]));
            zmax = zmax.max(x[2]);
            rmax = rmax.max(r2);
            mass += p.mass[i];
        } else if i < g.plate_particles && x[2] >= 0.0 {
            hole_r2 = hole_r2.min(r2);
        }
    }
    let debris = front.len();
    if debris == 0 {
        return CloudFigures {
            cloud_front: 0.0,
            cloud_front_robust: 0.0,
            cloud_width: 0.0,
            cloud_width_robust: 0.0,
            hole_diameter: if hole_r2.is_finite() { 2.0 * hole_r2.sqrt() } else { f64::NAN },
            front_velocity: 0.0,
            debris_mass: 0.0,
            debris_particles: 0,
        };
    }
    let z_robust = mass_quantile_from_top(&mut front, 1e-3);
    let r_robust = mass_quantile_from_top(&mut radial, 1e-3);
    let (mut mv, mut m) = (0.0, 0.0);
    for i in 0..p.len() {
        if p.x[i][2] >= z_robust {
            mv += p.mass[i] * p.v[i][2];
            m += p.mass[i];
        }
    }
    CloudFigures {
        cloud_front: zmax - g.rear_face,
        cloud_front_robust: z_robust - g.rear_face,
        cloud_width: 2.0 * rmax.sqrt(),
        cloud_width_robust: 2.0 * r_robust,
        hole_diameter: if hole_r2.is_finite() { 2.0 * hole_r2.sqrt() } else { f64::NAN },
        front_velocity: mv / m,
        debris_mass: mass,
        debris_particles: debris,
    }
}

/// A side view like a flash radiograph: particle mass projected along `y` onto the x-z
/// plane (which contains the flight axis), binned on `nx x nz` pixels over `[x0, x1] x
/// [z0, z1]`. Each particle's mass is spread evenly over a square `footprint` wide (its
/// lattice spacing), so a continuous body shows as a continuous density rather than as
/// dots. Returns areal density (kg/m^2) per pixel, row-major with z rows from `z0`.
pub fn radiograph(
    p: &Particles,
    x_range: (f64, f64),
    z_range: (f64, f64),
    nx: usize,
    nz: usize,
    footprint: f64,
) -> Vec<f64> {
    let mut img = vec![0.0; nx * nz];
    let (px, pz) = ((x_range.1 - x_range.0) / nx as f64, (z_range.1 - z_range.0) / nz as f64);
    // Sub-samples per axis: enough that the footprint covers every pixel it overlaps.
    let s = ((footprint / px.min(pz)).ceil() as usize).clamp(1, 16);
    let w = 1.0 / (s * s) as f64 / (px * pz);
    for (x, m) in p.x.iter().zip(&p.mass) {
        for a in 0..s {
            let xs = x[0] + footprint * ((a as f64 + 0.5) / s as f64 - 0.5);
            let i = ((xs - x_range.0) / px).floor();
            if i < 0.0 || i as usize >= nx {
                continue;
            }
            for b in 0..s {
                let zs = x[2] + footprint * ((b as f64 + 0.5) / s as f64 - 0.5);
                let k = ((zs - z_range.0) / pz).floor();
                if k >= 0.0 && (k as usize) < nz {
                    img[k as usize * nx + i as usize] += m * w;
                }
            }
        }
    }
    img
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn default_model_has_the_papers_particle_count_within_0_2_percent() {
        let (s, g) = Impact::default().setup().unwrap();
        assert_eq!(g.plate_particles, 836_352);
        assert_eq!(s.particles.len(), 848_104);
        assert!((s.particles.len() as f64 / 847_888.0 - 1.0).abs() < 0.002);
        let sphere_mass: f64 = s.particles.mass[g.plate_particles..].iter().sum();
        assert!((sphere_mass - 0.02006).abs() < 1e-4, "{sphere_mass}");
        let (lo, hi) = s.particles.bounding_box();
        assert!(hi[2] < PLATE_THICKNESS && lo[2] < -2.0 * SPHERE_RADIUS + 1e-3);
    }

    #[test]
    fn large_model_count_is_within_0_2_percent() {
        let imp = Impact { spacing: 0.21e-3, cell: 1.0e-3, ..Default::default() };
        assert_eq!(imp.plate_counts(), [667, 667, 30]);
    }

    #[test]
    fn measurements_of_a_synthetic_cloud() {
        let mut p = Particles::default();
        let g = ImpactGeometry { plate_particles: 2, rear_face: 1.0 };
        // Plate rim at r = 3 and r = 4, debris at z = 2..=1001 on the axis and one stray
        // particle far out.
        p.push([3.0, 0.0, 0.5], [0.0; 3], 1.0, 1.0, 1.0);
        p.push([0.0, 4.0, 0.5], [0.0; 3], 1.0, 1.0, 1.0);
        for k in 0..1000 {
            p.push([0.001 * k as f64, 0.0, 2.0 + k as f64], [0.0, 0.0, 5.0], 1.0, 1.0, 1.0);
        }
        p.push([50.0, 0.0, 5000.0], [0.0, 0.0, 9.0], 0.1, 1.0, 1.0);
        let f = measure(&p, &g);
        assert_eq!(f.debris_particles, 1001);
        assert_eq!(f.cloud_front, 4999.0);
        assert_eq!(f.cloud_width, 100.0);
        assert!(f.cloud_front_robust < 1001.0, "the stray particle is ignored: {}", f.cloud_front_robust);
        assert!(f.cloud_width_robust < 2.0, "{}", f.cloud_width_robust);
        assert_eq!(f.hole_diameter, 6.0);
    }

    #[test]
    fn radiograph_conserves_mass_inside_the_frame() {
        let (s, _) = Impact { spacing: 2.0e-3, ..Default::default() }.setup().unwrap();
        let img = radiograph(&s.particles, (-0.1, 0.1), (-0.05, 0.05), 80, 40, 2.0e-3);
        let pix = (0.2 / 80.0) * (0.1 / 40.0);
        let mass: f64 = img.iter().sum::<f64>() * pix;
        assert!((mass / s.particles.total_mass() - 1.0).abs() < 1e-9);
    }
}
