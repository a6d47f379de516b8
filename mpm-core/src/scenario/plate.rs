//! One-dimensional plate impact: the validation of shock capturing against the
//! Rankine-Hugoniot relations.
//!
//! A lead slab (paper Table 3, failure off) of length `L` along `z` moves at `-v` onto a
//! rigid wall at `z = 0`. It fills a thin column, `2 x 2` cells wide, whose four sides are
//! roller walls (slip: only the normal velocity is stopped), so the motion is uniaxial
//! strain. The slab touches the wall at `t = 0`; a shock runs from the wall into the slab and
//! brings the material behind it to rest, so the particle velocity jump across the shock is
//! `u_p = v` (one slab on a rigid wall was chosen over the symmetric impact of two slabs,
//! where `u_p = v/2`: the same physics without a contact interface in the middle). Theory
//! ([`rankine_hugoniot`]): the shock moves into the undisturbed slab at
//! `U_s = c0 + s u_p` and the shocked stress is `p = rho0 U_s u_p` (lead at 500 m/s:
//! 2,817 m/s and 16.0 GPa; at 3 km/s: 6,442 m/s and 219 GPa), the specific internal energy
//! rises by `u_p^2 / 2`.
//!
//! Measurements from particle data:
//! * [`shock_front`]: where the velocity, averaged over slices one cell thick, crosses the
//!   mean of the undisturbed slab's velocity and the wall's (`-v/2`), scanning from the free
//!   end towards the wall and interpolating linearly between slices;
//! * [`ShockTracker`]: the front over time while it is away from the wall and the free end;
//!   the shock speed is the least-squares slope of the later half of its path (the shock
//!   forms at the wall and settles over the first part of its run) plus `v` (the front moves
//!   at `U_s - u_p` in the lab frame, into material that moves at `-v`);
//! * [`shocked_state`]: means over the shocked material, excluding [`MARGIN_CELLS`] cells
//!   next to the wall (the impact face keeps a start-up error, "wall heating") and next to
//!   the front (the shock is spread over a few cells by the artificial viscosity): pressure
//!   and normal stress averaged over volume (`sum V_p sigma_p / sum V_p`, the stress the
//!   grid transmits), density as mass over volume, specific internal energy and the particle
//!   velocity jump (shocked minus undisturbed velocity, the latter averaged over the slab
//!   ahead of the front) averaged over mass.
//!
//! Each measurement takes [`Collectives`], so a run split over ranks measures its whole slab
//! (slice and region sums summed over the ranks, the free end a maximum); one process passes
//! [`crate::SingleProcess`].
//!
//! With linear shape functions the particles of one cell act on the grid only through their
//! cell's sum `sum V_p sigma_p`: the state of the individual particles behind a strong shock
//! scatters widely (at 3 km/s their densities by about 14 %) while the cell sums stay close
//! to the Rankine-Hugoniot state. Hence the volume averages.

use super::{fit_line, lattice, seed, Pick, Setup};
use crate::error::SimError;
use crate::exchange::Collectives;
use crate::grid::{GridSpec, Wall, WallKind};
use crate::material::{Eos, Material, MgForm, MieGruneisen};
use crate::particles::Particles;
use crate::solver::Simulation;
use serde::Serialize;

/// Default impact speed (m/s).
pub const DEFAULT_VELOCITY: f64 = 500.0;
/// Default slab length (m).
pub const DEFAULT_LENGTH: f64 = 100e-3;
/// Default cell size (m).
pub const DEFAULT_CELL: f64 = 0.5e-3;
/// Default particles per cell along each axis.
pub const DEFAULT_PARTICLES_PER_CELL: usize = 2;
/// Cells across the column in x and in y.
pub const COLUMN_CELLS: usize = 2;
/// Cells excluded next to the wall, the shock front and the free end by the measurements.
pub const MARGIN_CELLS: f64 = 4.0;
/// The run ends when the shock has crossed this fraction of the slab (by the
/// Rankine-Hugoniot speed), before it reaches the free end.
pub const END_FRACTION: f64 = 0.8;

/// A lead slab on a rigid wall in a laterally confined column.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct PlateImpact {
    /// Impact speed towards the wall (m/s, > 0).
    pub velocity: f64,
    /// Slab length along z (m).
    pub length: f64,
    /// Cell size (m).
    pub cell: f64,
    /// Particles per cell along each axis.
    pub particles_per_cell: usize,
    /// Mie-Grüneisen form.
    pub eos: MgForm,
}

impl Default for PlateImpact {
    fn default() -> Self {
        Self {
            velocity: DEFAULT_VELOCITY,
            length: DEFAULT_LENGTH,
            cell: DEFAULT_CELL,
            particles_per_cell: DEFAULT_PARTICLES_PER_CELL,
            eos: MgForm::default(),
        }
    }
}

/// What the measurements need to know about a plate impact.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct PlateGeometry {
    /// Impact speed (m/s); the slab moves at `-velocity` along z.
    pub velocity: f64,
    /// Slab length (m).
    pub length: f64,
    /// Cell size (m): the slice thickness of the profiles and the unit of the margins.
    pub cell: f64,
    /// The slab's Mie-Grüneisen constants.
    pub eos: MieGruneisen,
}

impl PlateImpact {
    /// Lead of Table 3 without failure.
    pub fn material(&self) -> Material {
        Material { name: "lead (Table 3, no failure)".into(), failure: None, ..Material::lead(self.eos) }
    }

    /// Build the slab, the column's grid and its five walls.
    pub fn setup(&self) -> Result<(Setup, PlateGeometry), SimError> {
        self.setup_picked(Pick::All)
    }

    /// Build the column's grid, its walls and the particles `pick` asks for.
    pub fn setup_picked(&self, pick: Pick<'_>) -> Result<(Setup, PlateGeometry), SimError> {
        for (name, v) in [("speed (m/s)", self.velocity), ("length (m)", self.length), ("cell size (m)", self.cell)] {
            if !(v.is_finite() && v > 0.0) {
                return Err(SimError::Config(format!("the plate impact {name} must be a finite number > 0, got {v}")));
            }
        }
        if self.particles_per_cell == 0 {
            return Err(SimError::Config("the plate impact needs at least 1 particle per cell".into()));
        }
        let cells_z = (self.length / self.cell).round() as usize;
        let min_cells = (8.0 * MARGIN_CELLS) as usize;
        if cells_z < min_cells {
            return Err(SimError::Config(format!(
                "a {} m slab is only {cells_z} cells of {} m long; the measurements need at least {min_cells} cells",
                self.length, self.cell
            )));
        }
        let material = self.material();
        let Eos::MieGruneisen(eos) = material.eos else { unreachable!("lead uses the Mie-Grüneisen EOS") };
        let ppc = self.particles_per_cell;
        let h = self.cell / ppc as f64;
        let width = COLUMN_CELLS as f64 * self.cell;
        let length = cells_z as f64 * self.cell;
        let n = [COLUMN_CELLS * ppc, COLUMN_CELLS * ppc, cells_z * ppc];
        let mass = material.density * h * h * h;
        let c = material.reference_sound_speed();
        let v = [0.0, 0.0, -self.velocity];
        let (particles, part) = seed(pick, n[0] * n[1] * n[2], [mass, material.density, c], |f| {
            lattice::for_each_cell_centre([0.0; 3], [h; 3], n, |x| f(x, v));
        });
        let slip = |axis, position| Wall { axis, position, kind: WallKind::Slip };
        let setup = Setup {
            scenario: "plate".into(),
            model: format!("plate-v{:.0}-dx{:.2}mm", self.velocity, self.cell * 1e3),
            particles,
            material,
            grid: GridSpec { dx: self.cell, anchor: [0.0; 3], cells: [COLUMN_CELLS, COLUMN_CELLS, cells_z + 2] },
            walls: vec![slip(0, 0.0), slip(0, width), slip(1, 0.0), slip(1, width), slip(2, 0.0)],
            spacing: [h; 3],
            part,
        };
        Ok((setup, PlateGeometry { velocity: self.velocity, length, cell: self.cell, eos }))
    }
}

impl PlateGeometry {
    /// The Rankine-Hugoniot state behind the shock (`u_p = v`).
    pub fn theory(&self) -> HugoniotState {
        rankine_hugoniot(&self.eos, self.velocity)
    }

    /// When to end the run: the shock, at its Rankine-Hugoniot speed, has crossed
    /// [`END_FRACTION`] of the slab (s).
    pub fn end_time(&self) -> f64 {
        END_FRACTION * self.length / self.theory().shock_speed
    }
}

/// The state behind a steady shock into material at rest in its reference state.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct HugoniotState {
    /// Particle velocity jump `u_p` (m/s).
    pub particle_velocity: f64,
    /// Shock speed relative to the undisturbed material, `U_s = c0 + s u_p` (m/s).
    pub shock_speed: f64,
    /// Shocked pressure (normal stress) `rho0 U_s u_p` (Pa).
    pub pressure: f64,
    /// Shocked density `rho0 U_s / (U_s - u_p)` (kg/m^3).
    pub density: f64,
    /// Specific internal energy gained, `u_p^2 / 2` (J/kg).
    pub specific_energy: f64,
}

/// The Rankine-Hugoniot jump for particle velocity `up` with the linear `U_s - u_p` relation
/// of the Mie-Grüneisen constants `eos`.
pub fn rankine_hugoniot(eos: &MieGruneisen, up: f64) -> HugoniotState {
    let us = eos.c0 + eos.s * up;
    HugoniotState {
        particle_velocity: up,
        shock_speed: us,
        pressure: eos.rho0 * us * up,
        density: eos.rho0 * us / (us - up),
        specific_energy: 0.5 * up * up,
    }
}

/// Mass-weighted mean z-velocity of the particles in slices `[k dx, (k+1) dx)`, k = 0, 1,
/// ...: `(slice centre, mean velocity)` for the non-empty slices, in increasing z.
///
/// Over ranks `particles` are this rank's: collective ([`Collectives`]: the highest z is a
/// maximum over ranks, the slices' sums are summed over ranks in rank order), the same
/// profile on every rank.
pub fn velocity_profile(
    particles: &Particles,
    g: &PlateGeometry,
    ranks: &mut dyn Collectives,
) -> Result<Vec<(f64, f64)>, SimError> {
    let mut top = [particles.x.iter().map(|x| x[2]).fold(0.0, f64::max)];
    ranks.max(&mut top)?;
    let slices = (top[0] / g.cell).floor() as usize + 1;
    // Per slice: momentum, mass.
    let mut acc = vec![0.0; 2 * slices];
    for ((x, v), m) in particles.x.iter().zip(&particles.v).zip(&particles.mass) {
        let k = ((x[2] / g.cell).floor().max(0.0) as usize).min(slices - 1);
        acc[2 * k] += m * v[2];
        acc[2 * k + 1] += m;
    }
    ranks.sum(&mut acc)?;
    Ok(acc
        .chunks_exact(2)
        .enumerate()
        .filter(|(_, a)| a[1] > 0.0)
        .map(|(k, a)| ((k as f64 + 0.5) * g.cell, a[0] / a[1]))
        .collect())
}

/// The shock front's z (m): where the slice velocity crosses `-v/2`, the mean of the
/// undisturbed slab's velocity `-v` and the wall's, found from the free end towards the
/// wall; `None` before the velocity anywhere has risen that far. Collective over ranks
/// ([`velocity_profile`]).
pub fn shock_front(
    particles: &Particles,
    g: &PlateGeometry,
    ranks: &mut dyn Collectives,
) -> Result<Option<f64>, SimError> {
    let profile = velocity_profile(particles, g, ranks)?;
    let level = -0.5 * g.velocity;
    let Some(k) = profile.iter().rposition(|&(_, v)| v >= level) else { return Ok(None) };
    let (z0, v0) = profile[k];
    Ok(Some(match profile.get(k + 1) {
        Some(&(z1, v1)) => z0 + (v0 - level) / (v0 - v1) * (z1 - z0),
        None => z0,
    }))
}

/// The z of the slab's free end: the farthest particle from the wall (m); a maximum over
/// ranks.
fn free_end(particles: &Particles, ranks: &mut dyn Collectives) -> Result<f64, SimError> {
    let mut end = [particles.x.iter().map(|x| x[2]).fold(f64::NEG_INFINITY, f64::max)];
    ranks.max(&mut end)?;
    Ok(end[0])
}

/// Means over the shocked material (see the module docs for the weights).
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct ShockedState {
    /// Particle velocity jump: shocked minus undisturbed z-velocity (m/s).
    pub particle_velocity: f64,
    /// Mean pressure `-tr(sigma) / 3`, volume average (Pa).
    pub pressure: f64,
    /// Normal stress `-sigma_zz`, volume average (Pa): the stress of the Rankine-Hugoniot
    /// momentum jump.
    pub normal_stress: f64,
    /// Density, mass over volume (kg/m^3).
    pub density: f64,
    /// Specific internal energy (J/kg).
    pub specific_energy: f64,
    /// Particles averaged over behind the front.
    pub particles: usize,
}

/// The shocked state behind a front at `front` (see the module docs); `None` if the shocked
/// or the undisturbed region, without its margins, holds no particle. Collective over ranks
/// (sums over ranks in rank order), the same on every rank.
pub fn shocked_state(
    particles: &Particles,
    g: &PlateGeometry,
    front: f64,
    ranks: &mut dyn Collectives,
) -> Result<Option<ShockedState>, SimError> {
    let margin = MARGIN_CELLS * g.cell;
    let end = free_end(particles, ranks)?;
    // ahead: momentum, mass; behind: mass, volume, momentum, V tr(sigma) / 3, V sigma_zz, m e
    let mut sums = [0.0; 8];
    let mut count = [0u64];
    for p in 0..particles.len() {
        let (z, m) = (particles.x[p][2], particles.mass[p]);
        if z > front + margin && z < end - margin {
            sums[0] += m * particles.v[p][2];
            sums[1] += m;
        } else if z > margin && z < front - margin {
            let s = &particles.stress[p];
            let vol = m / particles.rho[p];
            for (acc, val) in sums[2..].iter_mut().zip([
                m,
                vol,
                m * particles.v[p][2],
                vol * (s[0] + s[1] + s[2]) / 3.0,
                vol * s[2],
                m * particles.e_int[p],
            ]) {
                *acc += val;
            }
            count[0] += 1;
        }
    }
    ranks.sum(&mut sums)?;
    ranks.sum_counts(&mut count)?;
    let [ahead_mv, ahead_m, m, vol, mv, v_tr, v_zz, me] = sums;
    if count[0] == 0 || ahead_m == 0.0 {
        return Ok(None);
    }
    Ok(Some(ShockedState {
        particle_velocity: mv / m - ahead_mv / ahead_m,
        pressure: -v_tr / vol,
        normal_stress: -v_zz / vol,
        density: m / vol,
        specific_energy: me / m,
        particles: count[0] as usize,
    }))
}

/// The shock front's path `(time, z)` while the front is at least [`MARGIN_CELLS`] cells
/// from the wall and from the free end.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct ShockTracker {
    /// The plate.
    pub geometry: PlateGeometry,
    /// `(t, z_front)` samples (s, m).
    pub path: Vec<(f64, f64)>,
}

/// Measured shock against theory.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct PlateResult {
    /// Measured shock speed relative to the undisturbed slab (m/s).
    pub shock_speed: f64,
    /// Measured shocked state at the end of the run.
    pub shocked: ShockedState,
    /// Rankine-Hugoniot values for `u_p = v`.
    pub theory: HugoniotState,
    /// Front samples tracked (the fit uses the later half).
    pub samples: usize,
}

impl ShockTracker {
    /// An empty path for the plate `geometry`.
    pub fn new(geometry: PlateGeometry) -> Self {
        Self { geometry, path: Vec::new() }
    }

    /// Record the front of `sim`'s current state if it is away from the wall and the free
    /// end; whether it was recorded. Collective over ranks: every rank records the same path.
    pub fn observe(&mut self, sim: &Simulation, ranks: &mut dyn Collectives) -> Result<bool, SimError> {
        let p = sim.particles();
        let margin = MARGIN_CELLS * self.geometry.cell;
        // The front is the same on every rank, so they all take the same branch.
        let Some(z) = shock_front(p, &self.geometry, ranks)?.filter(|&z| z > margin) else { return Ok(false) };
        if z >= free_end(p, ranks)? - margin {
            return Ok(false);
        }
        self.path.push((sim.time(), z));
        Ok(true)
    }

    /// Shock speed relative to the undisturbed slab: the least-squares slope of the later
    /// half (in time) of the front's path plus `v` (m/s); `None` with fewer than two samples
    /// there.
    pub fn shock_speed(&self) -> Option<f64> {
        let (first, last) = (self.path.first()?.0, self.path.last()?.0);
        let later = self.path.partition_point(|s| s.0 < 0.5 * (first + last));
        fit_line(&self.path[later..]).map(|(slope, _)| slope + self.geometry.velocity)
    }

    /// The measurements on `sim`'s current state against theory; `None` if the front was
    /// never tracked or the shocked region is empty. Collective over ranks.
    pub fn result(&self, sim: &Simulation, ranks: &mut dyn Collectives) -> Result<Option<PlateResult>, SimError> {
        let Some(shock_speed) = self.shock_speed() else { return Ok(None) };
        let Some(front) = shock_front(sim.particles(), &self.geometry, ranks)? else { return Ok(None) };
        let Some(shocked) = shocked_state(sim.particles(), &self.geometry, front, ranks)? else { return Ok(None) };
        Ok(Some(PlateResult { shock_speed, shocked, theory: self.geometry.theory(), samples: self.path.len() }))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::exchange::SingleProcess;

    #[test]
    fn rankine_hugoniot_values_for_lead() {
        let (_, g) = PlateImpact::default().setup().unwrap();
        // U_s = 2092 + 1.45 * 500 = 2817 m/s; p = 11350 * 2817 * 500 = 15.986475 GPa.
        let t = g.theory();
        assert_eq!(t.shock_speed, 2817.0);
        assert!((t.pressure - 15.986_475e9).abs() < 1.0);
        assert!((t.density - 11350.0 * 2817.0 / 2317.0).abs() < 1e-9);
        assert_eq!(t.specific_energy, 125_000.0);
        // The Hugoniot-form EOS holds the shocked state exactly: p(mu, E = p eta / 2) = p.
        let mu = t.density / 11350.0 - 1.0;
        let e_vol = 11350.0 * t.specific_energy;
        assert!((g.eos.pressure_at(mu, e_vol) / t.pressure - 1.0).abs() < 1e-12);
    }

    #[test]
    fn setup_is_a_confined_column_moving_onto_the_wall() {
        let plate = PlateImpact::default();
        let (s, g) = plate.setup().unwrap();
        // 2 x 2 cells of 2 x 2 x 2 particles across, 200 cells long.
        assert_eq!(s.particles.len(), 16 * 400);
        assert_eq!(s.walls.len(), 5);
        assert!(s.material.failure.is_none());
        assert!(s.particles.v.iter().all(|v| *v == [0.0, 0.0, -500.0]));
        let mass = s.particles.total_mass();
        assert!((mass / (11350.0 * 1e-3 * 1e-3 * 0.1) - 1.0).abs() < 1e-12);
        assert_eq!(g.length, 0.1);
        assert!((g.end_time() - 0.8 * 0.1 / 2817.0).abs() < 1e-15);
        // At rest nothing has been shocked.
        assert_eq!(shock_front(&s.particles, &g, &mut SingleProcess).unwrap(), None);
        let bad = PlateImpact { velocity: -1.0, ..plate.clone() }.setup().unwrap_err();
        assert!(bad.to_string().contains("speed"), "{bad}");
        let short = PlateImpact { length: 5e-3, ..plate }.setup().unwrap_err();
        assert!(short.to_string().contains("cells"), "{short}");
    }

    #[test]
    fn front_and_shocked_state_of_a_synthetic_profile() {
        let (s, g) = PlateImpact::default().setup().unwrap();
        let mut p = s.particles;
        // A step at z = 40.2 mm: at rest below with a uniform stress, -500 m/s above.
        for i in 0..p.len() {
            if p.x[i][2] < 40.2e-3 {
                p.v[i] = [0.0; 3];
                p.stress[i] = [-15e9, -15e9, -16e9, 0.0, 0.0, 0.0];
                p.e_int[i] = 1.2e5;
            }
        }
        let front = shock_front(&p, &g, &mut SingleProcess).unwrap().unwrap();
        // Slice 80 ([40, 40.5) mm) holds particles at 40.125 and 40.375 mm of equal mass:
        // mean -250 m/s exactly at the level, so the front is its centre.
        assert!((front - 40.25e-3).abs() < 1e-12, "{front}");
        let st = shocked_state(&p, &g, front, &mut SingleProcess).unwrap().unwrap();
        assert!((st.particle_velocity - 500.0).abs() < 1e-9, "{}", st.particle_velocity);
        assert!((st.pressure / (46e9 / 3.0) - 1.0).abs() < 1e-12 && (st.normal_stress / 16e9 - 1.0).abs() < 1e-12);
        assert!((st.density / 11350.0 - 1.0).abs() < 1e-12 && (st.specific_energy / 1.2e5 - 1.0).abs() < 1e-12);
    }
}
