//! The hypervelocity impact of paper Section 6: a lead sphere (radius 7.5 mm, 20 g) at
//! 6.58 km/s, normal incidence, on a lead plate 6.35 mm thick and 140 mm x 140 mm (Table 3
//! with failure), compared at 30.6 µs after impact with a flash radiograph of the debris
//! cloud.
//!
//! Particles, as the particle generator of the paper's group (MPM3D) makes them, which gives
//! the paper's counts exactly: every particle has mass `rho0 h^3` for the spacing `h`;
//! * plate: a block of `n x n x t` particles at spacing `h`, cell-centred (the first particle
//!   `h/2` from the block's corner), `n = round(140 mm / h)`, `t = round(6.35 mm / h)`:
//!   264 x 264 x 12 at 0.53 mm (139.92 mm square, 6.36 mm thick), 667 x 667 x 30 at 0.21 mm;
//! * sphere: with `k = round(R / h)` (14 at 0.53 mm, 36 at 0.21 mm), the points
//!   `centre + ((i - 1/2) h, (j - 1/2) h, (l - 1/2) h)`, `i, j, l` in `1-k ..= k`, that lie
//!   strictly inside the radius `k h`: 11,536 at 0.53 mm (19.5 g), 195,360 at 0.21 mm
//!   (20.5 g);
//! * totals 847,888 and 13,542,030, the paper's counts.
//!
//! Geometry: the flight direction is `+z`. The plate fills `[-n h/2, n h/2]^2 x [0, t h]`, so
//! its front face is `z = 0` and its rear face `z = t h`; the sphere's centre is on the axis
//! at `z = -k h`, so the sphere of radius `k h` its points fill touches the plate at `t = 0`
//! and its nearest particles are one spacing from the plate's (impact time 0).
//!
//! Grid: cubic cells of `cell` (default 2.12 mm, so 4 x 4 x 4 particles per cell; 1.06 and
//! 1.59 mm are the paper's other options) on a lattice anchored at the plate's corner
//! `(-n h/2, -n h/2, 0)`, normally adaptive (it follows the debris cloud).
//!
//! Measurements ([`measure`]), all at the current state, with "debris" = every particle
//! beyond the plate's rear face:
//! * `cloud_front`: distance of the farthest debris particle centre from the rear face;
//!   `cloud_front_robust`: the same for the position beyond which lies 0.1 % of the debris
//!   mass (a few stray particles cannot move it);
//! * `cloud_width`: largest diameter normal to the flight direction, twice the largest
//!   distance of a debris particle centre from the flight axis; `cloud_width_robust`: twice
//!   the radius containing 99.9 % of the debris mass;
//! * `hole_diameter`: twice the smallest distance from the axis of a plate particle still
//!   inside the plate's slab `0 <= z <= t h` (the rim of the hole);
//! * `leading_debris_velocity`: mass-weighted mean z-velocity of the debris beyond the robust
//!   front (the speed of the leading 0.1 % of the debris now, not the speed at which the
//!   front has moved).
//!
//! Histories ([`History`]): the figures and energies sampled about every microsecond, and
//! [`History::front_velocity`], the least-squares slope of the robust front over the last
//! quarter of the run: the speed at which the cloud's leading edge has actually moved.
//!
//! Over ranks ([`measure_over`]) the hole is a minimum over the ranks and the debris's few
//! values per particle are gathered on rank 0 in the whole set's order, so the figures are
//! the ones one process computes from the same state.

use super::{lattice, seed, Pick, Setup};
use crate::error::SimError;
use crate::exchange::{Collectives, SingleProcess};
use crate::grid::GridSpec;
use crate::material::{Material, MgForm};
use crate::math::Vec3;
use crate::particles::Particles;
use crate::solver::Simulation;
use serde::{Deserialize, Serialize};

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
/// Default interval between history samples (s).
pub const DEFAULT_HISTORY_INTERVAL: f64 = 1e-6;
/// Particles of the paper's small model (0.53 mm spacing).
pub const PAPER_SMALL_MODEL_PARTICLES: usize = 847_888;
/// Particles of the paper's large model (0.21 mm spacing).
pub const PAPER_LARGE_MODEL_PARTICLES: usize = 13_542_030;

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
        Self { spacing: DEFAULT_SPACING, cell: DEFAULT_CELL, velocity: IMPACT_VELOCITY, eos: MgForm::default() }
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

/// The sphere's lattice points in half-spacing units: the odd integers `(a, b, c)` =
/// `(2i - 1, 2j - 1, 2l - 1)`, `i, j, l` in `1-k ..= k`, with `a^2 + b^2 + c^2 < 4 k^2`
/// (strictly inside the radius `k h`, decided exactly in integers), x fastest.
fn sphere_points(k: usize) -> impl Iterator<Item = [i64; 3]> {
    let k = k as i64;
    let odd = move || (1 - k..=k).map(|i| 2 * i - 1);
    let r2 = 4 * k * k;
    odd()
        .flat_map(move |c| odd().flat_map(move |b| odd().map(move |a| [a, b, c])))
        .filter(move |p| p[0] * p[0] + p[1] * p[1] + p[2] * p[2] < r2)
}

impl Impact {
    /// Plate lattice counts `[n, n, t]`.
    pub fn plate_counts(&self) -> [usize; 3] {
        let n = (PLATE_SIDE / self.spacing).round().max(1.0) as usize;
        [n, n, (PLATE_THICKNESS / self.spacing).round().max(1.0) as usize]
    }

    /// `k = round(R / h)`: the sphere's lattice has `2k` points across.
    pub fn sphere_k(&self) -> usize {
        (SPHERE_RADIUS / self.spacing).round().max(1.0) as usize
    }

    /// Particles of the plate and of the sphere, counted without generating them.
    pub fn particle_counts(&self) -> (usize, usize) {
        let [nx, ny, nz] = self.plate_counts();
        (nx * ny * nz, sphere_points(self.sphere_k()).count())
    }

    /// Build the plate and sphere particles and the grid.
    pub fn setup(&self) -> Result<(Setup, ImpactGeometry), SimError> {
        self.setup_picked(Pick::All)
    }

    /// Build the grid and the particles `pick` asks for (numbered as in the whole set: the
    /// plate first).
    pub fn setup_picked(&self, pick: Pick<'_>) -> Result<(Setup, ImpactGeometry), SimError> {
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
        let h = self.spacing;
        let n = self.plate_counts();
        let half = 0.5 * n[0] as f64 * h;
        let k = self.sphere_k();
        let zc = -(k as f64) * h;
        let mass = material.density * h * h * h;
        let (plate_count, sphere_count) = self.particle_counts();
        let sphere_v = [0.0, 0.0, self.velocity];
        let (particles, part) = seed(pick, plate_count + sphere_count, [mass, material.density, c], |f| {
            lattice::for_each_cell_centre([-half, -half, 0.0], [h; 3], n, |x| f(x, [0.0; 3]));
            for [a, b, l] in sphere_points(k) {
                f([0.5 * h * a as f64, 0.5 * h * b as f64, zc + 0.5 * h * l as f64], sphere_v);
            }
        });
        let rear_face = n[2] as f64 * h;
        let setup = Setup {
            scenario: "impact".into(),
            model: format!("impact-h{:.2}mm-dx{:.2}mm", h * 1e3, self.cell * 1e3),
            particles,
            material,
            grid: GridSpec {
                dx: self.cell,
                anchor: [-half, -half, 0.0],
                cells: [
                    (2.0 * half / self.cell).ceil() as usize,
                    (2.0 * half / self.cell).ceil() as usize,
                    (rear_face / self.cell).ceil() as usize,
                ],
            },
            walls: vec![],
            spacing: [h; 3],
            part,
        };
        Ok((setup, ImpactGeometry { plate_particles: plate_count, rear_face }))
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
    /// Mass-weighted z-velocity of the debris beyond the robust front (m/s): how fast the
    /// leading 0.1 % of the debris moves now.
    pub leading_debris_velocity: f64,
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

/// Values per debris particle that [`measure_over`] gathers: global id, z, squared distance
/// from the flight axis, mass, z-velocity.
const DEBRIS_ROW: usize = 5;

/// Measure the debris cloud and the hole of one process's particles (particle `p` is
/// particle `p` of the whole set).
pub fn measure(p: &Particles, g: &ImpactGeometry) -> CloudFigures {
    measure_over(p, |i| i as u64, g, &mut SingleProcess)
        .expect("one process's collectives cannot fail")
        .expect("one process is rank 0")
}

/// Measure the debris cloud and the hole of a set spread over ranks, `p` being this rank's
/// particles and `global_id` their indices in the whole set: collective (every rank calls
/// it, [`Collectives`]); the figures on rank 0, `None` on the others.
///
/// The hole is a minimum over ranks (exact). The cloud's figures need the debris as a
/// whole (the robust ones are mass quantiles), so its few values per particle (5: global
/// id, z, squared distance from the axis, mass, z-velocity) are gathered on rank 0 and put
/// in global id order, one process's order: the figures are computed from the same values
/// in the same order as one process holding every particle computes them. No other
/// particle data moves.
pub fn measure_over(
    p: &Particles,
    global_id: impl Fn(usize) -> u64,
    g: &ImpactGeometry,
    ranks: &mut dyn Collectives,
) -> Result<Option<CloudFigures>, SimError> {
    let mut debris = Vec::new();
    let mut hole_r2 = f64::INFINITY;
    for i in 0..p.len() {
        let x: Vec3 = p.x[i];
        let r2 = x[0] * x[0] + x[1] * x[1];
        if x[2] > g.rear_face {
            debris.extend_from_slice(&[global_id(i) as f64, x[2], r2, p.mass[i], p.v[i][2]]);
        } else if x[2] >= 0.0 && global_id(i) < g.plate_particles as u64 {
            hole_r2 = hole_r2.min(r2);
        }
    }
    let mut hole = [-hole_r2];
    ranks.max(&mut hole)?;
    let Some(rows) = ranks.gather(debris)? else { return Ok(None) };
    let mut rows: Vec<[f64; DEBRIS_ROW]> =
        rows.chunks_exact(DEBRIS_ROW).map(|r| r.try_into().expect("chunks of DEBRIS_ROW")).collect();
    rows.sort_unstable_by(|a, b| a[0].total_cmp(&b[0]));
    Ok(Some(cloud_figures(&rows, -hole[0], g)))
}

/// The figures of the debris `rows` ([`DEBRIS_ROW`] values each, in global id order) and
/// the hole's smallest squared radius `hole_r2` (infinite: no plate particle left in the
/// slab).
fn cloud_figures(rows: &[[f64; DEBRIS_ROW]], hole_r2: f64, g: &ImpactGeometry) -> CloudFigures {
    let hole_diameter = if hole_r2.is_finite() { 2.0 * hole_r2.sqrt() } else { f64::NAN };
    if rows.is_empty() {
        return CloudFigures {
            cloud_front: 0.0,
            cloud_front_robust: 0.0,
            cloud_width: 0.0,
            cloud_width_robust: 0.0,
            hole_diameter,
            leading_debris_velocity: 0.0,
            debris_mass: 0.0,
            debris_particles: 0,
        };
    }
    let mut front: Vec<(f64, f64)> = rows.iter().map(|r| (r[1], r[3])).collect();
    let mut radial: Vec<(f64, f64)> = rows.iter().map(|r| (r[2].sqrt(), r[3])).collect();
    let (mut zmax, mut rmax, mut mass) = (f64::NEG_INFINITY, 0.0f64, 0.0);
    for r in rows {
        zmax = zmax.max(r[1]);
        rmax = rmax.max(r[2]);
        mass += r[3];
    }
    let z_robust = mass_quantile_from_top(&mut front, 1e-3);
    let r_robust = mass_quantile_from_top(&mut radial, 1e-3);
    // Every particle at or beyond the robust front is debris (the front is a debris z).
    let (mut mv, mut m) = (0.0, 0.0);
    for r in rows.iter().filter(|r| r[1] >= z_robust) {
        mv += r[3] * r[4];
        m += r[3];
    }
    CloudFigures {
        cloud_front: zmax - g.rear_face,
        cloud_front_robust: z_robust - g.rear_face,
        cloud_width: 2.0 * rmax.sqrt(),
        cloud_width_robust: 2.0 * r_robust,
        hole_diameter,
        leading_debris_velocity: mv / m,
        debris_mass: mass,
        debris_particles: rows.len(),
    }
}

/// One sample of an impact's history.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct HistorySample {
    /// Time after impact (s).
    pub time: f64,
    /// Farthest debris particle beyond the rear face (m).
    pub cloud_front: f64,
    /// Front ignoring the leading 0.1 % of the debris mass (m).
    pub cloud_front_robust: f64,
    /// Largest debris diameter normal to the flight axis (m).
    pub cloud_width: f64,
    /// Diameter containing 99.9 % of the debris mass (m).
    pub cloud_width_robust: f64,
    /// Kinetic energy (J).
    pub kinetic: f64,
    /// Internal energy (J).
    pub internal: f64,
    /// Total energy (J).
    pub total: f64,
    /// Failed particles.
    pub failed: usize,
}

impl HistorySample {
    /// Measure `sim` now, over every rank's particles ([`measure_over`]): collective; the
    /// sample on rank 0, `None` on the others.
    pub fn of(
        sim: &Simulation,
        geometry: &ImpactGeometry,
        ranks: &mut dyn Collectives,
    ) -> Result<Option<Self>, SimError> {
        let failed = ranks.total(sim.particles().failed_count())?;
        let exchange = sim.exchange();
        let cloud = measure_over(sim.particles(), |p| exchange.global_id(p), geometry, ranks)?;
        Ok(cloud.map(|f| Self::from_figures(sim, &f, failed)))
    }

    /// The sample of `sim` now, its cloud `f` and `failed` particles measured already.
    pub fn from_figures(sim: &Simulation, f: &CloudFigures, failed: usize) -> Self {
        let d = sim.diagnostics();
        Self {
            time: sim.time(),
            cloud_front: f.cloud_front,
            cloud_front_robust: f.cloud_front_robust,
            cloud_width: f.cloud_width,
            cloud_width_robust: f.cloud_width_robust,
            kinetic: d.kinetic,
            internal: d.internal,
            total: d.total(),
            failed,
        }
    }
}

/// An impact's history: a sample at the first step in every `interval` of time (and, by
/// [`History::finish`], at the end).
///
/// Over ranks every rank keeps a history and calls [`History::observe`] after every step:
/// the decision to sample depends on the time alone (the same on every rank), so all of
/// them take part in each sample's collective measurement; rank 0 holds the samples.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct History {
    /// Interval between samples (s).
    pub interval: f64,
    /// The samples, in time order (rank 0's; empty on the other ranks).
    pub samples: Vec<HistorySample>,
    /// Time of the last sample taken (on every rank).
    #[serde(skip)]
    last_time: Option<f64>,
}

impl History {
    /// An empty history sampling every `interval` seconds.
    pub fn new(interval: f64) -> Result<Self, SimError> {
        if !(interval.is_finite() && interval > 0.0) {
            return Err(SimError::Config(format!(
                "the history interval must be a positive time in s (default {DEFAULT_HISTORY_INTERVAL}), got {interval}"
            )));
        }
        Ok(Self { interval, samples: Vec::new(), last_time: None })
    }

    /// The time of the last sample taken (`None` before the first): with `interval` and
    /// `samples`, what a continued run needs ([`History::resumed`]).
    pub fn last_time(&self) -> Option<f64> {
        self.last_time
    }

    /// A history continued from a saved one's `interval`, `samples` and [`History::last_time`].
    pub fn resumed(interval: f64, samples: Vec<HistorySample>, last_time: Option<f64>) -> Result<Self, SimError> {
        Ok(Self { samples, last_time, ..Self::new(interval)? })
    }

    /// Record a sample of `sim` if it has entered a new interval since the last sample (or
    /// none was taken yet); whether it did. Collective over ranks (see [`History`]).
    pub fn observe(
        &mut self,
        sim: &Simulation,
        geometry: &ImpactGeometry,
        ranks: &mut dyn Collectives,
    ) -> Result<bool, SimError> {
        let slot = |t: f64| (t / self.interval).floor() as u64;
        if self.last_time.is_some_and(|t| slot(sim.time()) <= slot(t)) {
            return Ok(false);
        }
        self.last_time = Some(sim.time());
        self.samples.extend(HistorySample::of(sim, geometry, ranks)?);
        Ok(true)
    }

    /// Record the final state from its figures, measured already over every rank (`cloud`
    /// on rank 0, `None` on the others; `failed` particles), unless the last sample already
    /// is at this time.
    pub fn finish(&mut self, sim: &Simulation, cloud: Option<&CloudFigures>, failed: usize) {
        if self.last_time.is_none_or(|t| t < sim.time()) {
            self.last_time = Some(sim.time());
            self.samples.extend(cloud.map(|f| HistorySample::from_figures(sim, f, failed)));
        }
    }

    /// The speed at which the debris cloud's leading edge has moved: the least-squares
    /// slope of the robust front against time over the samples in the last quarter of the
    /// sampled time span (m/s). `None` with fewer than two samples there.
    pub fn front_velocity(&self) -> Option<f64> {
        let (first, last) = (self.samples.first()?, self.samples.last()?);
        let from = last.time - 0.25 * (last.time - first.time);
        let points: Vec<(f64, f64)> =
            self.samples.iter().filter(|s| s.time >= from).map(|s| (s.time, s.cloud_front_robust)).collect();
        super::fit_line(&points).map(|(slope, _)| slope)
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
    fn small_model_has_the_papers_particle_count_and_layout() {
        let imp = Impact::default();
        assert_eq!(imp.plate_counts(), [264, 264, 12]);
        assert_eq!(imp.sphere_k(), 14);
        assert_eq!(imp.particle_counts(), (836_352, 11_536));
        let (s, g) = imp.setup().unwrap();
        assert_eq!(g.plate_particles, 836_352);
        assert_eq!(s.particles.len(), PAPER_SMALL_MODEL_PARTICLES);
        let h = DEFAULT_SPACING;
        let m = 11350.0 * h * h * h;
        assert!(s.particles.mass.iter().all(|&x| x == m), "every particle weighs rho0 h^3");
        // Sphere 11,536 h^3 rho0 = 19.5 g; plate 139.92 mm square, 6.36 mm thick.
        let sphere_mass: f64 = s.particles.mass[g.plate_particles..].iter().sum();
        assert!((sphere_mass - 0.01950).abs() < 5e-5, "{sphere_mass}");
        assert!((g.rear_face - 12.0 * h).abs() < 1e-15);
        let plate = &s.particles.x[..g.plate_particles];
        let (xmin, xmax) =
            plate.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), x| (a.min(x[0]), b.max(x[0])));
        assert!((xmax - xmin - 263.0 * h).abs() < 1e-12 && (xmax + xmin).abs() < 1e-12);
        // The sphere's nearest particle is one spacing from the plate's first layer, on axis
        // at half-spacings, all strictly inside k h of the centre (0, 0, -k h).
        let k = 14.0 * h;
        let sphere = &s.particles.x[g.plate_particles..];
        let front = sphere.iter().map(|x| x[2]).fold(f64::NEG_INFINITY, f64::max);
        assert!((0.5 * h - front - h).abs() < 1e-12, "gap {}", 0.5 * h - front);
        assert!(sphere.iter().all(|x| x[0] * x[0] + x[1] * x[1] + (x[2] + k).powi(2) < k * k));
        assert!(s.particles.v[g.plate_particles..].iter().all(|v| *v == [0.0, 0.0, IMPACT_VELOCITY]));
    }

    #[test]
    fn large_model_has_the_papers_particle_count() {
        let imp = Impact { spacing: 0.21e-3, cell: 1.0e-3, ..Default::default() };
        assert_eq!(imp.plate_counts(), [667, 667, 30]);
        assert_eq!(imp.sphere_k(), 36);
        let (plate, sphere) = imp.particle_counts();
        assert_eq!((plate, sphere), (13_346_670, 195_360));
        assert_eq!(plate + sphere, PAPER_LARGE_MODEL_PARTICLES);
        // 195,360 (0.21 mm)^3 x 11350 kg/m^3 = 20.5 g.
        assert!((sphere as f64 * 11350.0 * 0.21e-3f64.powi(3) - 0.0205).abs() < 5e-5);
    }

    #[test]
    fn sphere_points_are_the_odd_lattice_strictly_inside_k() {
        // k = 1: the 8 points (+-1/2, +-1/2, +-1/2) h lie at sqrt(3)/2 h < h.
        assert_eq!(sphere_points(1).count(), 8);
        // k = 2: of the 64 points of the 4^3 lattice, those with a^2 + b^2 + c^2 < 16 in
        // odd half-units: (1,1,1) 8, (1,1,3) 24 -> 32; (1,3,3) = 19 and (3,3,3) = 27 are out.
        assert_eq!(sphere_points(2).count(), 32);
        // Counting and generating agree, and points on the boundary sphere are excluded.
        for k in [3, 7, 14] {
            let r2 = 4 * (k as i64) * (k as i64);
            assert!(sphere_points(k).all(|p| p.iter().all(|c| c % 2 != 0) && p.iter().map(|c| c * c).sum::<i64>() < r2));
        }
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

    fn sample(time: f64, front: f64) -> HistorySample {
        HistorySample {
            time,
            cloud_front: front,
            cloud_front_robust: front,
            cloud_width: 0.0,
            cloud_width_robust: 0.0,
            kinetic: 0.0,
            internal: 0.0,
            total: 0.0,
            failed: 0,
        }
    }

    #[test]
    fn front_velocity_is_the_slope_over_the_last_quarter() {
        let mut h = History::new(1e-6).unwrap();
        assert_eq!(h.front_velocity(), None);
        // The front accelerates until 30 us, then moves at 5 km/s with +-0.1 mm of noise
        // alternating about the last quarter's centre (35 us), which leaves its slope alone:
        // only the last quarter (30-40 us) counts.
        for k in 0..=40 {
            let t = k as f64 * 1e-6;
            let front = if k <= 30 { 1e8 * t * t } else { 0.09 + 5000.0 * (t - 30e-6) };
            let noise = if k < 30 {
                0.0
            } else if k % 2 == 0 {
                1e-4
            } else {
                -1e-4
            };
            h.samples.push(sample(t, front + noise));
        }
        let v = h.front_velocity().unwrap();
        assert!((v - 5000.0).abs() < 1e-6, "{v}");
        assert!(History::new(0.0).is_err() && History::new(f64::NAN).is_err());
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
