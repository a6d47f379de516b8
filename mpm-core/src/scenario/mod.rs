//! Problem set-ups: the Taylor bar Models 1-4 ([`taylor`]) and lattice seeding helpers
//! ([`lattice`]). A scenario produces a [`Setup`]; [`crate::Simulation::new`] takes it.

pub mod impact;
pub mod lattice;
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
