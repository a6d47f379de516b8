//! Errors of the solver library. Every message says what went wrong and what to do.

use crate::math::Vec3;

/// Why a simulation could not be set up or could not continue.
#[derive(Debug, thiserror::Error, Clone, PartialEq)]
pub enum SimError {
    /// A configuration value is out of range.
    #[error("invalid configuration: {0}")]
    Config(String),
    /// The exchange between ranks failed (a particle moved past a neighbouring rank, a
    /// message had the wrong size).
    #[error("exchange between ranks failed: {0}")]
    Exchange(String),
    /// A material constant is out of range.
    #[error("invalid material '{name}': {problem}; correct the material's constants")]
    Material {
        /// The material's name.
        name: String,
        /// Which constant is wrong, its admissible range and its value.
        problem: String,
    },
    /// NaN or infinity appeared: the run has blown up.
    #[error("step {step}: {count} particle(s) have non-finite (NaN or infinite) state; the run blew up. Reduce the CFL number (now {cfl}) or check the material and initial conditions")]
    NonFinite {
        /// The step that produced them (1-based).
        step: u64,
        /// How many particles.
        count: u64,
        /// CFL number in use.
        cfl: f64,
    },
    /// Energy grew far beyond its initial value: the run is unstable.
    #[error("step {step}: total energy grew to {ratio:.2} times its initial value; the run is unstable. Reduce the CFL number (now {cfl})")]
    EnergyBlowUp {
        /// The step (1-based).
        step: u64,
        /// Total energy over initial total energy.
        ratio: f64,
        /// CFL number in use.
        cfl: f64,
    },
    /// Total energy rose above its initial value by more than the configured fraction.
    #[error("step {step}: total energy rose {:.2} % above its initial value, more than the limit of {:.2} %; the run is creating energy. Reduce the CFL number (now {cfl}), keep the artificial bulk viscosity on for shocks, or raise energy_rise_limit if the rise is expected", 100.0 * rise, 100.0 * limit)]
    EnergyRise {
        /// The step (1-based).
        step: u64,
        /// `(E - W_ext - E0) / E0`.
        rise: f64,
        /// The configured limit (fraction).
        limit: f64,
        /// CFL number in use.
        cfl: f64,
    },
    /// Particles left the fixed grid.
    #[error("step {step}: {count} particle(s) left the fixed grid (particle {first} at {position:?} m); use the adaptive grid or a larger fixed grid")]
    LeftGrid {
        /// The step (1-based).
        step: u64,
        /// How many particles.
        count: u64,
        /// Index of the first one.
        first: usize,
        /// Its position.
        position: Vec3,
    },
    /// The adaptive grid would exceed its node limit.
    #[error("step {step}: the adaptive grid would need {nodes} nodes, more than the limit of {limit}; particles have flown far apart. Raise the node limit (max_nodes) if memory allows, or end the run earlier")]
    GridTooLarge {
        /// The step (1-based).
        step: u64,
        /// Nodes needed.
        nodes: usize,
        /// The limit.
        limit: usize,
    },
    /// The simulation failed earlier and cannot continue.
    #[error("the simulation stopped with an error at step {0} and cannot continue; start a new one")]
    Poisoned(u64),
    /// The simulation's grid arrays were released after its last step.
    #[error("the simulation's grid arrays were released after step {0} (release_grid_arrays), so it cannot step again; start a new one")]
    Released(u64),
}
